"""Controllers and control targets: small immutable values.

A CBC controller (thesis eqs. 3.2, 3.15, 3.21, 3.27) is the PD law

.. math::

    u = k_p\\,(x_1^* - x_1) + k_d\\,(x_2^* - x_2)

on two measured signals ``x1, x2`` (e.g. a displacement and its derivative, or two
displacements). A *target* says where ``(x1*, x2*)`` is:

- :class:`FourierTarget` -- forced systems, eq. 3.3: ``x1*`` a truncated Fourier series in
  the phase ``θ = Ωt`` of the forcing generator and ``x2* = dx1*/dt``;
- :class:`EllipticTarget` -- PP-CBC, eqs. 3.13/3.14/3.28-3.29: a point on an ellipse
  chosen by the measured phase-plane angle ``φ``;
- :class:`PolarTarget` -- PP-CBC, eqs. 3.20-3.22: a point on a polar curve
  ``r*(φ)`` given by ``2 n_h + 1`` Fourier coefficients.

Targets are plain frozen dataclasses holding numbers. The virtual rig evaluates them inside
its compiled loop through :meth:`AbstractTarget.reference`, a pure JAX function of a flat
parameter vector (:meth:`AbstractTarget.vector`); changing a target's numbers therefore
never re-compiles anything, only a change of target *type* or size does.
"""

from __future__ import annotations

import abc
import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import ClassVar

import jax.numpy as jnp
import numpy as np

from bifid.errors import BifidInputError

Array = jnp.ndarray

POLAR_TABLE = 4096  # points of the tabulated polar target in the rig loop

__all__ = [
    "AbstractTarget",
    "EllipticTarget",
    "FourierTarget",
    "PDController",
    "PolarTarget",
    "harmonic_series",
]


def _finite(name: str, value: float) -> float:
    try:
        v = float(value)
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a number, got {value!r}.") from None
    if not math.isfinite(v):
        raise BifidInputError(f"{name} must be finite, got {value!r}.")
    return v


def _coefficients(name: str, values: Sequence[float] | np.ndarray) -> np.ndarray:
    arr = np.asarray(values, dtype=float).reshape(-1)
    if arr.size < 1 or arr.size % 2 != 1:
        raise BifidInputError(
            f"{name} must hold 2q+1 Fourier coefficients [c0, a1..aq, b1..bq], "
            f"got {arr.size} values."
        )
    if not np.all(np.isfinite(arr)):
        raise BifidInputError(f"{name} must be finite, got {arr.tolist()}.")
    arr.setflags(write=False)
    return arr


def harmonic_series(c: Array, cos1: Array, sin1: Array) -> tuple[Array, Array]:
    """Evaluate ``s(φ) = c0 + Σ_j a_j cos jφ + b_j sin jφ`` and ``ds/dφ`` from ``cos φ, sin φ``.

    ``c = [c0, a_1..a_q, b_1..b_q]``.
    """
    q = (c.shape[0] - 1) // 2
    if q == 0:
        return c[0], jnp.zeros_like(c[0])
    # one vectorised evaluation (fuses into a single kernel in the rig loop)
    k = jnp.arange(1, q + 1, dtype=c.dtype)
    phi = jnp.arctan2(sin1, cos1)
    ck, sk = jnp.cos(k * phi), jnp.sin(k * phi)
    a, b = c[1 : q + 1], c[q + 1 :]
    value = c[0] + jnp.sum(a * ck + b * sk)
    deriv = jnp.sum(k * (b * ck - a * sk))
    return value, deriv


def _angle(xi1: Array, xi2: Array) -> tuple[Array, Array, Array]:
    """``cos φ, sin φ, ρ`` of the point ``(ξ1, ξ2)``; ``φ = 0`` at the origin."""
    rho2 = xi1 * xi1 + xi2 * xi2
    safe = rho2 > 0.0
    rho = jnp.sqrt(jnp.where(safe, rho2, 1.0))
    c = jnp.where(safe, xi1 / rho, 1.0)
    s = jnp.where(safe, xi2 / rho, 0.0)
    return c, s, jnp.where(safe, rho, 0.0)


class AbstractTarget(abc.ABC):
    """A control target ``(x1*, x2*)`` as a function of the measured ``(x1, x2)`` and the
    forcing phase ``θ``.

    Subclasses are frozen dataclasses; :meth:`vector` packs their numbers into one float
    array and the static :meth:`reference` evaluates the target from it inside JAX code.
    """

    kind: ClassVar[str]

    @abc.abstractmethod
    def vector(self) -> np.ndarray:
        """The target's numbers as one flat float64 array."""

    @staticmethod
    @abc.abstractmethod
    def reference(
        vec: Array, x1: Array, x2: Array, theta: Array, omega: Array
    ) -> tuple[Array, Array]:
        """``(x1*, x2*)`` for measured ``x1, x2``, forcing phase ``θ`` and frequency ``Ω``."""

    @staticmethod
    def compile(vec: Array):
        """Work done once per rig block for :meth:`fast_reference` (default: none)."""
        return vec

    @classmethod
    def fast_reference(
        cls, aux, x1: Array, x2: Array, theta: Array, omega: Array
    ) -> tuple[Array, Array]:
        """:meth:`reference` from :meth:`compile`'s output, as evaluated in the rig loop."""
        return cls.reference(aux, x1, x2, theta, omega)

    @property
    def static_key(self) -> tuple:
        """What the compiled rig loop depends on (type and size, never the numbers)."""
        return (type(self), int(self.vector().shape[0]))


@dataclass(frozen=True, eq=False)
class FourierTarget(AbstractTarget):
    """Target of CBC for forced systems, thesis eq. 3.3.

    .. math::

        x^*(θ) = \\frac{A_0^*}{2} + \\sum_{j=1}^q A_j^*\\cos jθ + B_j^*\\sin jθ,
        \\qquad \\dot x^* = Ω\\,\\frac{dx^*}{dθ},

    with ``θ = Ωt`` the phase of the forcing generator (the force is
    ``γ cos(θ - ψ)``). The controller's ``x2`` must be the time derivative of ``x1``.

    Parameters
    ----------
    coefficients : array of shape (2q+1,)
        ``p* = [A0*, A1*..Aq*, B1*..Bq*]`` (the ordering of eq. 3.4).
    """

    kind: ClassVar[str] = "fourier"
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(1))

    def __post_init__(self) -> None:
        object.__setattr__(self, "coefficients", _coefficients("coefficients", self.coefficients))

    @property
    def n_harmonics(self) -> int:
        return (self.coefficients.shape[0] - 1) // 2

    def vector(self) -> np.ndarray:
        c = np.array(self.coefficients, dtype=float)
        c[0] = 0.5 * c[0]
        return c

    @staticmethod
    def reference(vec, x1, x2, theta, omega):
        value, deriv = harmonic_series(vec, jnp.cos(theta), jnp.sin(theta))
        return value, omega * deriv


@dataclass(frozen=True)
class EllipticTarget(AbstractTarget):
    """Elliptic PP-CBC target, thesis eqs. 3.13 and 3.17.

    .. math::

        φ = \\operatorname{atan2}\\bigl((x_2 - o_2)/ω,\\ x_1 - o_1\\bigr),\\quad
        x_1^* = o_1 + A\\cos φ,\\quad x_2^* = o_2 + ωA\\sin φ .

    With ``x2 = ẋ1`` the orbit ``x1 = o1 + A cos(Ω t)`` has ``ẋ1 = -ΩA sin(Ωt)``: use
    ``omega = -Ω`` (eqs. 3.14, 3.28-3.29; the sign of ω sets the sense of rotation).
    With two displacements rotating counter-clockwise (Example 3.2) use ``omega > 0``.

    Parameters
    ----------
    amplitude : float
        ``A* >= 0``.
    omega : float
        ``ω*`` (non-zero; the aspect ratio of the ellipse, signed).
    offset : (float, float)
        Centre ``(o1*, o2*)``.
    """

    kind: ClassVar[str] = "elliptic"
    amplitude: float = 0.0
    omega: float = 1.0
    offset: tuple[float, float] = (0.0, 0.0)

    def __post_init__(self) -> None:
        a = _finite("amplitude", self.amplitude)
        if a < 0:
            raise BifidInputError(f"amplitude must be >= 0, got {a!r}.")
        w = _finite("omega", self.omega)
        if w == 0.0:
            raise BifidInputError("omega must be non-zero (it scales the second coordinate).")
        off = tuple(_finite("offset", v) for v in self.offset)
        if len(off) != 2:
            raise BifidInputError(f"offset must be two numbers (o1, o2), got {self.offset!r}.")
        object.__setattr__(self, "amplitude", a)
        object.__setattr__(self, "omega", w)
        object.__setattr__(self, "offset", off)

    def vector(self) -> np.ndarray:
        return np.array([self.amplitude, self.omega, self.offset[0], self.offset[1]])

    @staticmethod
    def reference(vec, x1, x2, theta, omega):
        amp, w, o1, o2 = vec[0], vec[1], vec[2], vec[3]
        c, s, _ = _angle(x1 - o1, (x2 - o2) / w)
        return o1 + amp * c, o2 + w * amp * s

    def phase(self, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
        """The angle ``φ`` of eq. 3.13 for measured samples."""
        return np.arctan2(
            (np.asarray(x2) - self.offset[1]) / self.omega, np.asarray(x1) - self.offset[0]
        )


@dataclass(frozen=True, eq=False)
class PolarTarget(AbstractTarget):
    """General polar-curve PP-CBC target, thesis eqs. 3.20-3.22.

    In the coordinates ``ξ = T⁻¹ (x - o)`` (the linear change of coordinates of
    eq. 3.12, generalised to any invertible 2x2 ``T``; ``T = diag(scale)``, ``o = 0`` with
    ``scale = (1, 1)`` is eq. 3.21 as printed)

    .. math::

        φ = \\operatorname{atan2}(ξ_2, ξ_1),\\quad
        r^*(φ) = a_0^* + \\sum_{j=1}^{n_h} a_j^*\\cos jφ + b_j^*\\sin jφ,\\quad
        x^* = o + T\\, r^*(φ) (\\cos φ, \\sin φ)^T .

    Choosing ``T`` from the first harmonics of a measured orbit (``x - o ≈ a cos θ +
    b sin θ``, ``T = [a b] / |(a_1, b_1)|``) maps its ellipse to a circle: ``r*(φ)`` is then
    nearly constant, its harmonics (set by the orbit's nonlinearity only) decay fast, and
    ``a0`` is close to the first-harmonic amplitude of ``x1``.

    Parameters
    ----------
    coefficients : array of shape (2 n_h + 1,)
        ``[a0*, a1*..a_nh*, b1*..b_nh*]`` (eq. 3.24 ordering; ``a0`` is the mean radius).
    scale : (float, float)
        ``T = diag(scale)`` when ``transform`` is not given.
    origin : (float, float)
        ``o``.
    transform : 2x2 nested tuple, optional
        ``T`` (rows), invertible.
    """

    kind: ClassVar[str] = "polar"
    coefficients: np.ndarray = field(default_factory=lambda: np.zeros(1))
    scale: tuple[float, float] = (1.0, 1.0)
    origin: tuple[float, float] = (0.0, 0.0)
    transform: tuple[tuple[float, float], tuple[float, float]] | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "coefficients", _coefficients("coefficients", self.coefficients))
        sc = tuple(_finite("scale", v) for v in self.scale)
        if len(sc) != 2 or 0.0 in sc:
            raise BifidInputError(f"scale must be two non-zero numbers, got {self.scale!r}.")
        org = tuple(_finite("origin", v) for v in self.origin)
        if len(org) != 2:
            raise BifidInputError(f"origin must be two numbers, got {self.origin!r}.")
        object.__setattr__(self, "scale", sc)
        object.__setattr__(self, "origin", org)
        if self.transform is not None:
            T = np.asarray(self.transform, dtype=float)
            if T.shape != (2, 2) or not np.all(np.isfinite(T)):
                raise BifidInputError(f"transform must be a finite 2x2 matrix, got {T!r}.")
            if abs(np.linalg.det(T)) <= 1e-14 * max(np.max(np.abs(T)) ** 2, 1e-300):
                raise BifidInputError(f"transform must be invertible, got {T.tolist()}.")
            object.__setattr__(self, "transform", (tuple(T[0]), tuple(T[1])))

    @property
    def matrix(self) -> np.ndarray:
        """``T`` as a 2x2 array."""
        if self.transform is not None:
            return np.array(self.transform, dtype=float)
        return np.diag(np.asarray(self.scale, dtype=float))

    @property
    def n_harmonics(self) -> int:
        return (self.coefficients.shape[0] - 1) // 2

    def vector(self) -> np.ndarray:
        return np.concatenate([self.matrix.ravel(), self.origin, self.coefficients])

    @staticmethod
    def _xi(head, x1, x2):
        t11, t12, t21, t22, o1, o2 = (head[i] for i in range(6))
        det = t11 * t22 - t12 * t21
        d1, d2 = x1 - o1, x2 - o2
        return (t22 * d1 - t12 * d2) / det, (t11 * d2 - t21 * d1) / det

    @staticmethod
    def _back(head, r, c, s):
        t11, t12, t21, t22, o1, o2 = (head[i] for i in range(6))
        return o1 + r * (t11 * c + t12 * s), o2 + r * (t21 * c + t22 * s)

    @staticmethod
    def reference(vec, x1, x2, theta, omega):
        xi1, xi2 = PolarTarget._xi(vec, x1, x2)
        c, s, _ = _angle(xi1, xi2)
        r, _ = harmonic_series(vec[6:], c, s)
        return PolarTarget._back(vec, r, c, s)

    @staticmethod
    def compile(vec: Array):
        # r*(φ) tabulated on POLAR_TABLE points of [-π, π): the rig loop then needs one
        # atan2 and a linear interpolation per sample instead of 2 n_h sines and cosines.
        # Interpolation error <= (Δφ)²/8 max|r*''| ≈ 3e-7 Σ_k k² |c_k| (negligible
        # against the 1e-4 tolerances of the protocols).
        phi = -jnp.pi + (2.0 * jnp.pi / POLAR_TABLE) * jnp.arange(POLAR_TABLE + 1)
        c = vec[6:]
        q = (c.shape[0] - 1) // 2
        k = jnp.arange(1, q + 1, dtype=vec.dtype)
        r = c[0] + jnp.cos(phi[:, None] * k) @ c[1 : q + 1] + jnp.sin(phi[:, None] * k) @ c[q + 1 :]
        return vec[:6], r

    @classmethod
    def fast_reference(cls, aux, x1, x2, theta, omega):
        head, table = aux
        xi1, xi2 = PolarTarget._xi(head, x1, x2)
        c, s, _ = _angle(xi1, xi2)
        u = (jnp.arctan2(s, c) + jnp.pi) * (POLAR_TABLE / (2.0 * jnp.pi))
        i = jnp.clip(jnp.floor(u), 0, POLAR_TABLE - 1)
        f = u - i
        i = i.astype(jnp.int32)
        r = table[i] + f * (table[i + 1] - table[i])
        return PolarTarget._back(head, r, c, s)

    def with_coefficients(self, coefficients: np.ndarray) -> PolarTarget:
        """Same coordinates (transform, origin), new coefficients."""
        return PolarTarget(
            coefficients=coefficients,
            scale=self.scale,
            origin=self.origin,
            transform=self.transform,
        )

    def polar(self, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``(φ, r)`` of measured samples in the target's coordinates ``ξ``."""
        xi1, xi2 = self.to_xi(x1, x2)
        return np.arctan2(xi2, xi1), np.hypot(xi1, xi2)

    def to_xi(self, x1: np.ndarray, x2: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """``ξ = T⁻¹ (x - o)`` of samples."""
        Ti = np.linalg.inv(self.matrix)
        d1 = np.asarray(x1, dtype=float) - self.origin[0]
        d2 = np.asarray(x2, dtype=float) - self.origin[1]
        return Ti[0, 0] * d1 + Ti[0, 1] * d2, Ti[1, 0] * d1 + Ti[1, 1] * d2


@dataclass(frozen=True)
class PDController:
    """PD feedback ``u = kp (x1* - x1) + kd (x2* - x2)`` (thesis eqs. 3.2, 3.15, 3.21, 3.27).

    ``u`` enters the system along its ``input_direction`` (for ``flutter`` the heave
    equation, ``e_c = [0, 1, 0, 0, 0, 0]`` of eq. 3.25). ``x1`` and ``x2`` name rig
    signals: a measured output (``"h"``) or the rig's estimate of its time derivative
    (``"h_dot"``).

    With ``filter_hz`` the law's output passes a first-order low-pass before the
    actuator, ``u_k = u_{k-1} + a (u_law,k - u_{k-1})``, ``a = 1 - exp(-2π f_c / f_s)``
    (continuous equivalent ``u̇ = 2π f_c (u_law - u)``). Measurement noise is white up
    to the Nyquist frequency, so the gains pass it on to the actuator in full; the filter
    keeps only the fraction ``≈ (π f_c / 2) / (f_s / 2)`` of its power. Being linear and
    time-invariant it changes nothing at a non-invasive target (``u_law ≡ 0 ⇒ u ≡ 0``);
    its phase lag at the orbit's frequency must stay small against the loop's margins
    (checked by :func:`~bifid.cbc.controlled_floquet`, which includes the filter).

    Parameters
    ----------
    kp, kd : float
        Proportional and derivative (second-signal) gains.
    x1, x2 : str
        Names of the two measured signals.
    filter_hz : float, optional
        Cut-off [Hz] of the output low-pass (None: no filter).
    """

    kp: float
    kd: float
    x1: str
    x2: str
    filter_hz: float | None = None

    def __post_init__(self) -> None:
        object.__setattr__(self, "kp", _finite("kp", self.kp))
        object.__setattr__(self, "kd", _finite("kd", self.kd))
        if self.filter_hz is not None:
            fc = _finite("filter_hz", self.filter_hz)
            if fc <= 0:
                raise BifidInputError(f"filter_hz must be > 0 Hz (or None), got {fc!r}.")
            object.__setattr__(self, "filter_hz", fc)
        for name in ("x1", "x2"):
            v = getattr(self, name)
            if not isinstance(v, str) or not v:
                raise BifidInputError(f"{name} must name a rig signal, got {v!r}.")

    def to_json(self) -> dict:
        return {
            "kp": self.kp,
            "kd": self.kd,
            "x1": self.x1,
            "x2": self.x2,
            "filter_hz": self.filter_hz,
        }

    def filter_coefficient(self, sample_rate: float) -> float:
        """``a`` of the discrete output filter at ``sample_rate`` (1: no filter)."""
        if self.filter_hz is None:
            return 1.0
        return 1.0 - math.exp(-2.0 * math.pi * self.filter_hz / float(sample_rate))

    @staticmethod
    def law(gains: Array, x1: Array, x2: Array, r1: Array, r2: Array) -> Array:
        """``u = kp (r1 - x1) + kd (r2 - x2)`` with ``gains = [kp, kd]``."""
        return gains[0] * (r1 - x1) + gains[1] * (r2 - x2)


def target_to_json(target: AbstractTarget | None) -> dict | None:
    """A JSON-able description of a target (for dataset settings and reports)."""
    if target is None:
        return None
    if isinstance(target, FourierTarget):
        return {"kind": target.kind, "coefficients": target.coefficients.tolist()}
    if isinstance(target, EllipticTarget):
        return {
            "kind": target.kind,
            "amplitude": target.amplitude,
            "omega": target.omega,
            "offset": list(target.offset),
        }
    if isinstance(target, PolarTarget):
        return {
            "kind": target.kind,
            "coefficients": target.coefficients.tolist(),
            "transform": target.matrix.tolist(),
            "origin": list(target.origin),
        }
    return {"kind": getattr(target, "kind", type(target).__name__)}

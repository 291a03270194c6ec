"""Collocation in a rescaled time: a mesh whose points follow the orbit's arclength.

An orbit with fast phases (a relaxation oscillation, a canard) needs thousands of
Fourier modes in the uniform time ``tau = 2 pi t / T``; in a rescaled time it needs few.
The physical time of a mesh point is

.. math::

    t(\\tau) = \\frac{T}{2\\pi} \\theta(\\tau),\\qquad
    \\theta(\\tau) = \\int_0^\\tau h(\\sigma)\\,d\\sigma,

with a smooth positive 2π-periodic density ``h`` of mean 1 (so ``theta(2 pi) = 2 pi``),
fixed between mesh updates and represented by its values on the mesh (its trigonometric
interpolant). ``dx/dtau = (T / 2 pi) h(tau) f(x)``, so the collocation equations (thesis
eq. 4.12) become ``D_M v - (T / 2 pi) h_k f(v_k, lambda) = 0``; the integral phase
condition and the arclength equation are unchanged in ``tau``, and the Jacobian only gets
``h_k`` in its block diagonal and its ``T`` and ``lambda`` columns.

A :class:`Mesh` is the number of points ``M`` (it *is* that int) carrying its density
(``None``: uniform, ``h = 1``), so every piece of the mesh ladder (``_mesh``) that
handles sizes handles rescaled meshes too; :func:`convert_values` carries mesh values between
any two meshes, ``x_new(tau') = x_old(theta_old^{-1}(theta_new(tau')))`` through the
trigonometric interpolant (exact for the interpolant when both are uniform).

**The density** (:func:`equidistributing_mesh`). In the physical phase ``theta`` the
orbit's speed is ``sigma = |dx/dtheta|`` (states scaled by their ranges, so the measure
is unit-free); the monitor ``w = sigma + floor * mean(sigma)`` gives a share of the
points to the arclength and the rest to the time. Equidistributing ``w`` makes
``dtau'/dtheta`` proportional to it, so ``h = mean(w) / w`` in the new coordinate.
``log w`` and ``log h`` are low-passed (harmonics up to ``M / band``) so that ``h`` itself
is resolved on the mesh, and ``max h / min h <= MAX_DENSITY_RATIO``. A sharper density
resolves the fast phases better but is itself harder to resolve; the best band depends
on the orbit, so every band of :data:`DENSITY_BANDS` (and the uniform mesh, and the
current density carried onto the new number of points) is tried and the mesh on which
the orbit's interpolant has the smallest spectral tail is taken. Interpolants are read
at non-uniform points from a finer uniform grid (``_read``), not by dense sums.

**Reading a rescaled orbit in time.** The period is ``T``; peak values and peak-to-peak
amplitudes are those of the mesh values' interpolant (invariant); means and Fourier
coefficients in time carry the weight ``h`` (``int x dt = (T / 2 pi) int x h dtau``:
:func:`time_mean`); the variational equation in ``tau`` is scaled by the same ``h``
(the multipliers are invariant; the collocation operator's eigenvalues give them as on a
uniform mesh). Orbits leave the continuation as samples at uniform physical times
(:func:`uniform_samples`: the interpolant evaluated at ``theta^{-1}(2 pi k / N)``), so
every sample of a branch is at a known time ``T k / N``.
"""

from __future__ import annotations

import math

import numpy as np

from bifid.continuation._fourier import resample_orbit
from bifid.signal import spectral_tail

#: relative weights of time against arclength in the monitor tried (module docstring)
ARCLENGTH_FLOORS = (0.3,)
#: the density keeps harmonics up to ``M / band`` (of log h), for the bands tried
DENSITY_BANDS = (4, 6, 8, 12, 16, 24, 32)
#: largest ratio ``max h / min h``
MAX_DENSITY_RATIO = 1e3
_NEWTON_ITERS = 50


class Mesh(int):
    """A collocation mesh: ``M`` points (the int value) at ``tau_k = 2 pi k / M`` whose
    physical times follow the density ``h`` (module docstring); ``density=None`` is the
    uniform mesh. Equal to ``M`` as an int; :func:`same_mesh` also compares densities."""

    density: np.ndarray | None

    def __new__(cls, M: int, density: np.ndarray | None = None) -> Mesh:
        obj = super().__new__(cls, int(M))
        if density is not None:
            density = np.asarray(density, dtype=float)
            if density.shape != (int(M),) or not np.all(density > 0):
                raise ValueError("a mesh density needs M positive values")
        obj.density = density
        return obj

    def __repr__(self) -> str:
        kind = "uniform" if self.density is None else "rescaled"
        return f"Mesh({int(self)}, {kind})"

    def __reduce__(self):
        return (Mesh, (int(self), self.density))


def density_of(M: int) -> np.ndarray | None:
    """The density of a mesh (None: uniform; a plain int is uniform)."""
    return getattr(M, "density", None)


def density_values(M: int) -> np.ndarray:
    """``h_k`` on the mesh (ones for a uniform mesh)."""
    h = density_of(M)
    return np.ones(int(M)) if h is None else h


def same_mesh(a: int, b: int) -> bool:
    """Same number of points and the same density."""
    ha, hb = density_of(a), density_of(b)
    if int(a) != int(b) or (ha is None) != (hb is None):
        return False
    return ha is None or ha is hb or bool(np.array_equal(ha, hb))


def _grid(M: int) -> np.ndarray:
    return 2.0 * np.pi * np.arange(int(M)) / int(M)


#: fast evaluation of an interpolant: its values on a grid this many times finer (by FFT
#: zero padding), read by local Lagrange interpolation on this many nodes; for a harmonic
#: ``k <= M / 2`` the error is below ``3e-4 (pi k / (M UPSAMPLE))^STENCIL`` of its
#: amplitude (< 2e-14 for the highest), so it matches the dense trigonometric sum to
#: rounding while costing ``O(M log M + N)`` instead of ``O(M N)``
_UPSAMPLE = 32
_STENCIL = 10
_BARYCENTRIC = np.array([(-1.0) ** i * math.comb(_STENCIL - 1, i) for i in range(_STENCIL)])


def _fine_spectrum(values: np.ndarray) -> np.ndarray:
    """``rfft`` of the interpolant of periodic ``values`` (M, ...) on ``UPSAMPLE * M``
    points, scaled to values (the Nyquist cosine split over its two harmonics)."""
    M = values.shape[0]
    c = np.fft.rfft(values, axis=0) * _UPSAMPLE
    if M % 2 == 0:
        c[-1] = c[-1] / 2.0
    fine = np.zeros(((_UPSAMPLE * M) // 2 + 1, *c.shape[1:]), dtype=complex)
    fine[: c.shape[0]] = c
    return fine


def _fine_values(spectrum: np.ndarray) -> np.ndarray:
    return np.fft.irfft(spectrum, n=2 * (spectrum.shape[0] - 1), axis=0)


def _read(fine: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The periodic function sampled on the uniform grid ``fine`` (F, ...) at ``tau``
    (1-D), by barycentric Lagrange interpolation on the ``STENCIL`` nearest nodes."""
    F = fine.shape[0]
    x = np.mod(tau, 2.0 * np.pi) * (F / (2.0 * np.pi))
    base = np.floor(x).astype(int) - (_STENCIL // 2 - 1)
    d = (x - base)[:, None] - np.arange(_STENCIL)
    exact = d == 0.0
    w = _BARYCENTRIC / np.where(exact, 1.0, d)
    vals = fine[(base[:, None] + np.arange(_STENCIL)) % F]  # (N, STENCIL, ...)
    out = np.einsum("ni,ni...->n...", w, vals) / w.sum(axis=1).reshape(
        (-1,) + (1,) * (vals.ndim - 2)
    )
    hit = np.flatnonzero(exact.any(axis=1))
    if hit.size:
        out[hit] = vals[hit, np.argmax(exact[hit], axis=1)]
    return out


class _Phase:
    """``theta(tau) = int_0^tau h`` and ``h`` of the interpolant of a density, for fast
    reading at many points (``_read``)."""

    def __init__(self, h: np.ndarray) -> None:
        spec = _fine_spectrum(np.asarray(h, dtype=float))
        self.mean = spec[0].real / (2 * (spec.shape[0] - 1))
        k = np.arange(spec.shape[0])
        anti = np.zeros_like(spec)
        anti[1:] = spec[1:] / (1j * k[1:])
        periodic = _fine_values(anti)
        self.periodic = periodic - periodic[0]
        self.h = _fine_values(spec)

    def theta(self, tau: np.ndarray) -> np.ndarray:
        return self.mean * tau + _read(self.periodic, tau)


def phase(h: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """``theta(tau) = int_0^tau h`` of the interpolant of ``h`` (mean 1 assumed)."""
    return _Phase(h).theta(np.asarray(tau, dtype=float).ravel()).reshape(np.shape(tau))


def inverse_phase(h: np.ndarray, theta: np.ndarray) -> np.ndarray:
    """``tau`` with ``theta(tau) = theta`` (Newton's method from the linear interpolant of
    ``theta`` on the fine grid; ``theta`` is strictly increasing as ``h > 0``)."""
    shape = np.shape(theta)
    theta = np.asarray(theta, dtype=float).ravel()
    ph = _Phase(h)
    F = ph.h.shape[0]
    grid = 2.0 * np.pi * np.arange(F + 1) / F
    on_grid = ph.mean * grid + np.append(ph.periodic, 0.0)
    wrapped = np.mod(theta, 2 * np.pi)
    tau = np.interp(wrapped, on_grid, grid) + (theta - wrapped)
    for _ in range(_NEWTON_ITERS):
        dt = (ph.theta(tau) - theta) / _read(ph.h, tau)
        tau = tau - dt
        if np.max(np.abs(dt), initial=0.0) < 1e-12:  # quadratic: the error is now ~1e-24
            break
    return tau.reshape(shape)


def interpolate(V: np.ndarray, tau: np.ndarray) -> np.ndarray:
    """The trigonometric interpolant of mesh values ``V`` (M, ...) at ``tau`` (1-D)."""
    V = np.asarray(V, dtype=float)
    return _read(_fine_values(_fine_spectrum(V)), np.asarray(tau, dtype=float))


def source_points(M_from: int, M_to: int) -> np.ndarray:
    """The ``tau`` of mesh ``M_from`` at the physical times of the points of ``M_to``."""
    h_to, h_from = density_of(M_to), density_of(M_from)
    theta = _grid(M_to) if h_to is None else phase(h_to, _grid(M_to))
    return theta if h_from is None else inverse_phase(h_from, theta)


def convert_values(V: np.ndarray, M_from: int, M_to: int) -> np.ndarray:
    """Mesh values ``(M_from, n)`` carried onto ``M_to`` (same orbit, same times)."""
    if density_of(M_from) is None and density_of(M_to) is None:
        return resample_orbit(V, int(M_to))
    if same_mesh(M_from, M_to):
        return np.array(V, dtype=float)
    return interpolate(V, source_points(M_from, M_to))


def time_mean(V: np.ndarray, M: int) -> np.ndarray:
    """Mean over time of the orbit's mesh values ``(M, n)``:
    ``(1 / 2 pi) int x(tau) h(tau) dtau`` (the trapezoidal rule, spectrally accurate)."""
    V = np.asarray(V, dtype=float)
    h = density_of(M)
    return V.mean(axis=0) if h is None else (V * h[:, None]).mean(axis=0)


def uniform_samples(V: np.ndarray, M: int, n_samples: int | None = None) -> np.ndarray:
    """The orbit at the physical times ``t_k = T k / N`` (``N = n_samples``, default
    ``M``): the mesh values themselves on a uniform mesh of ``N`` points."""
    N = int(M) if n_samples is None else int(n_samples)
    return convert_values(V, M, N)


def _derivative(V: np.ndarray) -> np.ndarray:
    """``dV/dtau`` of the trigonometric interpolant at the mesh points (by FFT; the
    Nyquist harmonic, a cosine sampled, has no derivative there)."""
    M = V.shape[0]
    c = np.fft.rfft(V, axis=0)
    k = np.arange(c.shape[0])
    if M % 2 == 0:
        k[-1] = 0
    return np.fft.irfft(1j * k[:, None] * c, n=M, axis=0)


def _low_pass(values: np.ndarray, keep: int) -> np.ndarray:
    """Periodic values with their harmonics above ``keep`` removed (a smooth taper)."""
    c = np.fft.rfft(values)
    k = np.arange(c.shape[0])
    c *= np.exp(-((k / max(keep, 1)) ** 2) * np.log(10.0) * 4)  # 1e-4 at k = keep
    return np.fft.irfft(c, n=values.shape[0])


def equidistributing_mesh(V: np.ndarray, M_from: int, M_to: int) -> Mesh:
    """A mesh of ``M_to`` points whose density equidistributes the orbit's arclength
    (module docstring), from its mesh values ``V`` on ``M_from``: of the densities of
    every floor in :data:`ARCLENGTH_FLOORS` and band in :data:`DENSITY_BANDS` (and the
    uniform mesh, and the density of ``M_from`` itself carried onto ``M_to`` points), the
    one on which the orbit's interpolant has the smallest spectral tail."""
    V = np.asarray(V, dtype=float)
    best, best_tail = Mesh(M_to), np.inf
    if np.ptp(V) == 0:
        return best
    candidates = [Mesh(M_to)]
    h_old = density_of(M_from)
    if h_old is not None:
        # the current time: on more points it resolves what it resolved on fewer
        h = h_old if int(M_to) == int(M_from) else interpolate(h_old, _grid(M_to))
        if np.all(h > 0):
            candidates.append(Mesh(M_to, h / h.mean()))
    candidates += [
        _density_mesh(V, M_from, M_to, floor, band)
        for floor in ARCLENGTH_FLOORS
        for band in DENSITY_BANDS
    ]
    for mesh in candidates:
        tail = spectral_tail(convert_values(V, M_from, mesh))
        if tail < best_tail:
            best, best_tail = mesh, tail
    return best


def _density_mesh(V: np.ndarray, M_from: int, M_to: int, floor: float, band: int) -> Mesh:
    """The mesh of ``M_to`` points equidistributing the monitor with ``floor``, its
    density low-passed to harmonics up to ``M_to / band`` (module docstring)."""
    h_old = density_values(M_from)
    scale = np.ptp(V, axis=0)
    scale = np.where(scale > 0, scale, 1.0)
    # speed in the physical phase: dx/dtheta = (dx/dtau) / h
    speed = np.linalg.norm(_derivative(V / scale), axis=1) / h_old
    mean_speed = float(np.mean(speed * h_old))  # (1 / 2 pi) int sigma dtheta
    w = speed + floor * mean_speed
    w = np.exp(_low_pass(np.log(w), 2 * int(M_to) // band))
    # the new coordinate: dtau'/dtau = g = w h_old / mean(w h_old)
    g = w * h_old
    g = g / g.mean()
    tau_old = inverse_phase(g, _grid(M_to))  # the old tau of each new point
    log_h = np.log(interpolate(h_old, tau_old) / interpolate(g, tau_old))
    log_h = _low_pass(log_h, int(M_to) // band)
    log_h = np.maximum(log_h, log_h.max() - np.log(MAX_DENSITY_RATIO))
    h = np.exp(log_h)
    return Mesh(M_to, h / h.mean())


#: samples of a rescaled orbit at uniform times for the integrated variational equation
#: (``_floquet`` reads them at ``T j / K``, ``K`` a power of two up to this: exact nodes)
INTEGRATION_SAMPLES = 4096
#: largest spectral tail of uniform samples read between their nodes
_SAMPLES_TAIL = 1e-12


def integration_samples(V: np.ndarray, M: int) -> np.ndarray:
    """Mesh values as ``_floquet.floquet`` takes them (uniform times): the values
    themselves on a uniform mesh; else the fewest uniform samples ``M 2^j`` whose
    interpolant resolves the orbit, or :data:`INTEGRATION_SAMPLES` (whose nodes are the
    times read)."""
    if density_of(M) is None:
        return np.asarray(V, dtype=float)
    N = int(M)
    while N < INTEGRATION_SAMPLES:
        U = uniform_samples(V, M, N)
        if spectral_tail(U) <= _SAMPLES_TAIL:
            return U
        N *= 2
    return uniform_samples(V, M, INTEGRATION_SAMPLES)


#: most samples per orbit of a rescaled branch's exported orbits
MAX_EXPORT_SAMPLES = 16384


def export_samples(orbits: list[np.ndarray], meshes: list[int], tol: float) -> np.ndarray:
    """Orbits, each ``(M_i, n)`` on its own mesh ``M_i`` (uniform or rescaled), as
    samples at uniform times ``T j / N``, ``N`` the smallest ``max(M_i) 2^j`` on which
    every orbit is resolved (spectral tail at most ``tol``; at most
    :data:`MAX_EXPORT_SAMPLES`): ``(k, N, n)``, the orbits as every reader of uniform
    mesh values expects them."""
    N = max(int(m) for m in meshes)
    while True:
        out = np.array([uniform_samples(o, m, N) for o, m in zip(orbits, meshes, strict=True)])
        if 2 * N > MAX_EXPORT_SAMPLES or all(
            np.ptp(u) == 0 or spectral_tail(u) <= tol for u in out
        ):
            return out
        N *= 2

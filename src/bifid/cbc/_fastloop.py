"""The virtual rig's sample loop compiled with numba, for the reference systems.

Why hand-written, and why numba
-------------------------------
A virtual rig advances one sample at a time: measure, run the controller, hold its output
for one sample interval, integrate. At 5 kHz that is millions of tiny sequential steps of
a 2-6-state system. No ODE library serves this well: diffrax's per-step machinery and
XLA's per-operation dispatch on CPU cost ~5 µs a sample inside a ``lax.scan`` (the JAX
engine of :mod:`bifid.cbc._virtual`, 20-40x real time), far from the 200x a campaign of
thousands of simulated seconds needs. A plain loop compiled by numba costs a few hundred
nanoseconds per sample. The integrator is the same classic RK4 per sample interval as the
JAX engine (and is validated the same way: against :func:`bifid.simulate`, i.e. diffrax,
and against the JAX engine sample for sample).

What is compiled here
---------------------
- the vector fields of the built-in systems (``hopf``, ``vanderpol``, ``flutter``,
  ``duffing``, ``shaw_pierre``), each checked against the system's JAX ``field`` at the
  rig's parameters whenever they change (:func:`numba_field_agrees`); a rig whose system
  has none here (a user-registered system) uses the JAX engine;
- the three targets of :mod:`bifid.cbc._controllers` (Fourier, elliptic, tabulated polar)
  with the same formulas as their ``fast_reference``;
- the loop itself (:func:`run_block`): noise from an array drawn by the rig (the same
  array the JAX engine would get), derivative estimate, PD law, saturation, zero-order
  hold, harmonic forcing, ``substeps`` RK4 steps per sample.

Everything sits in one module-level function compiled once and cached on disk
(``cache=True``): no compilation per rig, per parameter or per target.
"""

from __future__ import annotations

import functools
import math

import numpy as np

try:  # numba is a dependency; the rig falls back to the JAX engine if it cannot load
    import numba

    HAVE_NUMBA = True
except ImportError:  # pragma: no cover - exercised only on broken installs
    numba = None
    HAVE_NUMBA = False

__all__ = [
    "HAVE_NUMBA",
    "SYSTEM_IDS",
    "TARGET_KINDS",
    "field_batch",
    "pack_target",
    "prepare_constants",
    "run_block",
]

# Systems with a compiled field (the name alone is not trusted: every rig checks the
# compiled field against system.field at its parameters before using it).
SYSTEM_IDS: dict[str, int] = {
    "hopf": 1,
    "vanderpol": 2,
    "flutter": 3,
    "duffing": 4,
    "shaw_pierre": 5,
}
# target kind -> code in the loop (0: no controller)
TARGET_KINDS: dict[str, int] = {"fourier": 1, "elliptic": 2, "polar": 3}


def _njit(fn):
    if not HAVE_NUMBA:
        return fn
    return numba.njit(cache=True, nogil=True)(fn)


@functools.lru_cache(maxsize=1)
def _flutter_prepare_jit():
    import jax

    from bifid.cbc._fastfield import _flutter_prepare

    return jax.jit(_flutter_prepare)


def prepare_constants(name: str, p: np.ndarray) -> np.ndarray:
    """Parameter-only work done once per run (``flutter``: ``A, n2, n3`` of eq. A.1)."""
    if name == "flutter":
        A, n2, n3 = _flutter_prepare_jit()(np.asarray(p, dtype=float))
        return np.concatenate([np.asarray(A).ravel(), np.asarray(n2), np.asarray(n3)])
    return np.asarray(p, dtype=np.float64).copy()


def pack_target(kind: str, vec: np.ndarray, table_size: int) -> np.ndarray:
    """The numbers the loop needs for a target (``polar``: head + tabulated ``r*(φ)``)."""
    vec = np.asarray(vec, dtype=np.float64)
    if kind != "polar":
        return vec.copy()
    # r*(φ) on table_size + 1 points of [-π, π], as PolarTarget.compile does
    phi = -np.pi + (2.0 * np.pi / table_size) * np.arange(table_size + 1)
    c = vec[6:]
    q = (c.shape[0] - 1) // 2
    k = np.arange(1, q + 1, dtype=np.float64)
    r = c[0] + np.cos(phi[:, None] * k) @ c[1 : q + 1] + np.sin(phi[:, None] * k) @ c[q + 1 :]
    return np.concatenate([vec[:6], r])


@_njit
def _field(sys_id, x, c, out):
    if sys_id == 3:  # flutter: z' = A z + (n2 + n3 α) α²
        a = x[2]
        a2 = a * a
        for i in range(6):
            s = 0.0
            for j in range(6):
                s += c[6 * i + j] * x[j]
            out[i] = s + (c[36 + i] + c[42 + i] * a) * a2
    elif sys_id == 1:  # hopf, eq. 5.2
        r2 = x[0] * x[0] + x[1] * x[1]
        g = (c[0] - c[1]) + c[2] * r2 - c[4] * r2 * r2
        out[0] = g * x[0] - c[3] * x[1]
        out[1] = g * x[1] + c[3] * x[0]
    elif sys_id == 2:  # vanderpol, eq. 5.14
        out[0] = x[1]
        out[1] = 2.0 * c[0] * x[1] - x[0] * x[0] * x[1] - x[0]
    elif sys_id == 4:  # duffing
        out[0] = x[1]
        out[1] = -2.0 * c[0] * x[1] - x[0] - c[1] * x[0] * x[0] * x[0]
    elif sys_id == 5:  # shaw_pierre
        k, c1, c2, kap = c[0], c[1], c[2], c[3]
        x1, v1, x2, v2 = x[0], x[1], x[2], x[3]
        out[0] = v1
        out[1] = -2.0 * k * x1 + k * x2 - (c1 + c2) * v1 + c2 * v2 - kap * x1 * x1 * x1
        out[2] = v2
        out[3] = k * x1 - 2.0 * k * x2 + c2 * v1 - (c1 + c2) * v2
    else:
        for i in range(out.shape[0]):
            out[i] = np.nan


@_njit
def field_batch(sys_id, xs, c):
    """``field(x, c)`` for each row of ``xs`` (to check against ``system.field``)."""
    out = np.empty_like(xs)
    for m in range(xs.shape[0]):
        _field(sys_id, xs[m], c, out[m])
    return out


@_njit
def _angle(xi1, xi2):
    rho2 = xi1 * xi1 + xi2 * xi2
    if rho2 > 0.0:
        rho = math.sqrt(rho2)
        return xi1 / rho, xi2 / rho
    return 1.0, 0.0


@_njit
def _reference(kind, tv, x1, x2, theta, om):
    """``(x1*, x2*)``: the targets' ``fast_reference`` (see :mod:`._controllers`)."""
    if kind == 1:  # Fourier series in θ (c0 already halved) and Ω d/dθ
        q = (tv.shape[0] - 1) // 2
        value = tv[0]
        deriv = 0.0
        c1, s1 = math.cos(theta), math.sin(theta)
        # the JAX target evaluates cos/sin of k·atan2(sin θ, cos θ); the same angle
        phi = math.atan2(s1, c1)
        for j in range(1, q + 1):
            ck, sk = math.cos(j * phi), math.sin(j * phi)
            a, b = tv[j], tv[q + j]
            value += a * ck + b * sk
            deriv += j * (b * ck - a * sk)
        return value, om * deriv
    if kind == 2:  # ellipse: amplitude, ω, offset
        amp, w, o1, o2 = tv[0], tv[1], tv[2], tv[3]
        c, s = _angle(x1 - o1, (x2 - o2) / w)
        return o1 + amp * c, o2 + w * amp * s
    # polar curve: head = T (row-major), origin; then r*(φ) tabulated on [-π, π]
    t11, t12, t21, t22, o1, o2 = tv[0], tv[1], tv[2], tv[3], tv[4], tv[5]
    det = t11 * t22 - t12 * t21
    d1, d2 = x1 - o1, x2 - o2
    c, s = _angle((t22 * d1 - t12 * d2) / det, (t11 * d2 - t21 * d1) / det)
    n = tv.shape[0] - 7
    u = (math.atan2(s, c) + math.pi) * (n / (2.0 * math.pi))
    i = math.floor(u)
    if i < 0.0:
        i = 0.0
    elif i > n - 1:
        i = n - 1.0
    f = u - i
    ii = int(i)
    r = tv[6 + ii] + f * (tv[7 + ii] - tv[6 + ii])
    return o1 + r * (t11 * c + t12 * s), o2 + r * (t21 * c + t22 * s)


@_njit
def run_block(sys_id, c, bvec, evec, x, yprev, dfilt, uprev, out_idx, noise,
              forced, gamma, om, psi, theta0,
              tkind, tv, s1, s1d, s2, s2d, kp, kd, ctrl_on, umax, afilt,
              deriv_state, alpha, dt, substeps, record,
              Y, YD, U, REF, XS):
    """Advance the rig by ``noise.shape[0]`` samples (see :mod:`bifid.cbc._virtual`).

    ``x``, ``yprev``, ``dfilt`` are updated in place; returns ``(uprev, n_done)`` where
    ``n_done`` < n means the state became non-finite at sample ``n_done`` (the rows from
    there on are NaN).
    """
    n = noise.shape[0]
    ns = x.shape[0]
    no = out_idx.shape[0]
    fx = np.empty(ns)
    k1 = np.empty(ns)
    k2 = np.empty(ns)
    k3 = np.empty(ns)
    k4 = np.empty(ns)
    xi = np.empty(ns)
    y = np.empty(no)
    yd = np.empty(no)
    h = dt / substeps
    for k in range(n):
        theta = theta0 + om * (k * dt)
        if record:  # the true state at t_k, when y_k is measured
            for i in range(ns):
                XS[k, i] = x[i]
        _field(sys_id, x, c, fx)
        for i in range(no):
            y[i] = x[out_idx[i]] + noise[k, i]
        fk = 0.0
        ph = 0.0
        if forced:
            ph = theta - psi
            fk = gamma * math.cos(ph)
        if deriv_state:
            for i in range(no):
                j = out_idx[i]
                yd[i] = fx[j] + bvec[j] * fk + evec[j] * uprev
        else:
            for i in range(no):
                raw = (y[i] - yprev[i]) / dt
                dfilt[i] = dfilt[i] + alpha * (raw - dfilt[i])
                yd[i] = dfilt[i]
        u = 0.0
        ref = np.nan
        if tkind > 0:
            x1 = yd[s1] if s1d else y[s1]
            x2 = yd[s2] if s2d else y[s2]
            r1, r2 = _reference(tkind, tv, x1, x2, theta, om)
            u = ctrl_on * (kp * (r1 - x1) + kd * (r2 - x2))
            if afilt < 1.0:  # first-order output low-pass (PDController.filter_hz)
                u = uprev + afilt * (u - uprev)
            if ctrl_on > 0.0:
                ref = r1
        if u > umax:
            u = umax
        elif u < -umax:
            u = -umax
        # zero-order hold: u fixed over [t_k, t_k + dt), `substeps` RK4 steps
        for sub in range(substeps):
            f0 = 0.0
            fm = 0.0
            f1 = 0.0
            if forced:
                f0 = gamma * math.cos(ph + om * (sub * h))
                fm = gamma * math.cos(ph + om * ((sub + 0.5) * h))
                f1 = gamma * math.cos(ph + om * ((sub + 1.0) * h))
            if sub == 0:
                for i in range(ns):
                    k1[i] = fx[i] + evec[i] * u + bvec[i] * f0
            else:
                _field(sys_id, x, c, k1)
                for i in range(ns):
                    k1[i] += evec[i] * u + bvec[i] * f0
            for i in range(ns):
                xi[i] = x[i] + 0.5 * h * k1[i]
            _field(sys_id, xi, c, k2)
            for i in range(ns):
                k2[i] += evec[i] * u + bvec[i] * fm
                xi[i] = x[i] + 0.5 * h * k2[i]
            _field(sys_id, xi, c, k3)
            for i in range(ns):
                k3[i] += evec[i] * u + bvec[i] * fm
                xi[i] = x[i] + h * k3[i]
            _field(sys_id, xi, c, k4)
            for i in range(ns):
                k4[i] += evec[i] * u + bvec[i] * f1
                x[i] = x[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0
        for i in range(no):
            Y[k, i] = y[i]
            YD[k, i] = yd[i]
            yprev[i] = y[i]
        U[k] = u
        REF[k] = ref
        uprev = u
        finite = True
        for i in range(ns):
            if not math.isfinite(x[i]):
                finite = False
        if not finite:
            for m in range(k + 1, n):
                for i in range(no):
                    Y[m, i] = np.nan
                    YD[m, i] = np.nan
                U[m] = np.nan
                REF[m] = np.nan
            return uprev, k
    return uprev, n

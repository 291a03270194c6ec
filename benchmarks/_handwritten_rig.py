"""The hand-written per-system numba kernels the virtual rig used before its sample loop was
generated from each system's field -- kept here only as the baseline of
``benchmarks/bench_rig.py`` (same loop, fixed-step RK4 without error control or safety gate,
one hand-coded field per built-in system addressed by ``SYSTEM_IDS``).
"""

from __future__ import annotations

import math

import numba
import numpy as np

from bifid.cbc._fastloop import _reference  # the targets, as in the generated loop

__all__ = ["SYSTEM_IDS", "field_batch", "prepare_constants", "run_block"]

# Systems with a hand-written field.
SYSTEM_IDS: dict[str, int] = {
    "hopf": 1,
    "vanderpol": 2,
    "flutter": 3,
    "duffing": 4,
    "shaw_pierre": 5,
}


def _njit(fn):
    return numba.njit(cache=True, nogil=True)(fn)


def prepare_constants(name: str, p: np.ndarray) -> np.ndarray:
    """Parameter-only work done once per run (``flutter``: ``A, n2, n3`` of eq. A.1)."""
    p = np.asarray(p, dtype=np.float64)
    if name != "flutter":
        return p.copy()
    from bifid.systems import flutter_matrices

    # z' = A z + (n2 + n3 α) α² in the interleaved order (h, ḣ, α, α̇, w, ẇ)
    M, D, K = (np.asarray(a) for a in flutter_matrices(p))
    Mi = np.linalg.inv(M)
    pos, vel = [0, 2, 4], [1, 3, 5]
    A = np.zeros((6, 6))
    A[pos, vel] = 1.0
    A[np.ix_(vel, pos)] = -Mi @ K
    A[np.ix_(vel, vel)] = -Mi @ D
    col = np.zeros(6)
    col[vel] = -Mi[:, 1]
    return np.concatenate([A.ravel(), col * p[10], col * p[11]])


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
def run_block(
    sys_id,
    c,
    bvec,
    evec,
    x,
    yprev,
    dfilt,
    uprev,
    out_idx,
    noise,
    forced,
    gamma,
    om,
    psi,
    theta0,
    tkind,
    tv,
    s1,
    s1d,
    s2,
    s2d,
    kp,
    kd,
    ctrl_on,
    umax,
    afilt,
    deriv_state,
    alpha,
    dt,
    substeps,
    record,
    Y,
    YD,
    U,
    REF,
    XS,
):
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

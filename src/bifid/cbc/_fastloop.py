"""The virtual rig's sample loop, compiled with numba for each system's own field.

This module is a template: :mod:`bifid.cbc._compiled` writes a module made of this source
followed by the scalar code generated from a system's JAX field (``_prepare``, ``_field``,
``N_STATES`` and ``N_COEF``, see :mod:`bifid.cbc._codegen`, which replace the placeholders
below), and numba compiles that module once and caches it on disk. Every system --
built-in, from a file or registered by a user -- runs through the same loop.

Why hand-written, and why numba
-------------------------------
A virtual rig advances one sample at a time: measure, run the controller, hold its output
for one sample interval, integrate. At 5 kHz that is millions of tiny sequential steps of
a 2-6-state system. No ODE library serves this well: diffrax's per-step machinery and
XLA's per-operation dispatch on CPU cost microseconds a sample inside a ``lax.scan`` (the
JAX engine, :mod:`bifid.cbc._jaxloop`), far from the hundreds of times real time a
campaign of thousands of simulated seconds needs. A plain loop compiled by numba costs a
few hundred nanoseconds per sample.

What one sample does (:func:`run_block`)
----------------------------------------
measurement ``y_k = C x_k + ε_k``; derivative estimate; the target's reference and the PD
law on the measurements, its first-order output filter; the safety gate (true state
inside the envelope, controller output within the actuator limit, everything finite);
saturation; then the interval ``[t_k, t_k + Δt)`` with the control held (zero-order hold)
and the harmonic force, by ``m`` classic RK4 steps of ``h = Δt/m``.

Error control. Each RK4 step also gives, at no extra field evaluation, the embedded
third-order solution with weights ``(1/6, 1/3, 1/3, 0, 1/6)`` on the stages
``k_1..k_4`` and ``k_5 = f(x_{n+1})`` (the first stage of the next step), hence the local
error estimate ``e = h (k_4 - k_5) / 6``. The interval is accepted when every step has
``|e_i| <= (rtol · max(|x_i|, |x_{n+1,i}|, s_i) + atol) / m`` for every state, ``s_i``
being the largest ``|x_i|`` seen so far on the rig (error per unit step: the ``m`` steps
of an interval together stay within the tolerance, whatever ``m``); otherwise it is
repeated with ``2m`` steps (up to ``m_max``, beyond which the gate trips). After an
interval accepted with a 32-fold margin the next one uses ``m/2`` steps again (never
fewer than the rig's ``substeps``). While the tolerance holds with ``m = substeps`` the
result is exactly that of fixed-step RK4.
"""

from __future__ import annotations

import math

import numba
import numpy as np

# Trip codes returned by run_block (the rig turns them into a Measurement.reason).
TRIP_NONE, TRIP_STATE, TRIP_CONTROL, TRIP_ACCURACY, TRIP_NONFINITE, TRIP_SIGNAL = range(6)


def _njit(fn):
    # error_model="numpy": 1/0 gives inf (the gate then trips), never a Python exception
    return numba.njit(cache=True, nogil=True, error_model="numpy")(fn)


# -- placeholders: a generated module redefines these with the system's own field -------
N_STATES = 1  # compile-time constants of the generated module (loops over states unroll)
N_COEF = 1


@_njit
def _prepare(p, r, d):  # d <- the parameter-only values the field needs
    d[0] = math.nan
    return d


@_njit
def _field(x, d, out):  # out <- f(x, p) given d = _prepare(p, r, d)
    for i in range(out.shape[0]):
        out[i] = math.nan
    return out


# -- targets (the formulas of the targets' fast_reference in bifid.cbc._controllers) ----
@_njit
def _angle(xi1, xi2):
    rho2 = xi1 * xi1 + xi2 * xi2
    if rho2 > 0.0:
        rho = math.sqrt(rho2)
        return xi1 / rho, xi2 / rho
    return 1.0, 0.0


@_njit
def _reference(kind, tv, x1, x2, theta, om):
    """``(x1*, x2*)`` of a Fourier (1), elliptic (2) or tabulated polar (3) target."""
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
def field_batch(xs, p, r):
    """``f(x, p)`` for each row of ``xs`` (to check the generated field against JAX)."""
    d = _prepare(p, r, np.empty(N_COEF))
    out = np.empty_like(xs)
    for m in range(xs.shape[0]):
        _field(xs[m], d, out[m])
    return out


# outcome of one interval (_interval)
AMPLE, ACCEPT, REJECT, NONFINITE = range(4)


@_njit
def _interval(x, fx, xn, fn, d, bvec, evec, u, force, dt, m, tol, xscale, work):
    """Integrate ``[t_k, t_k + dt)`` from ``x`` (field ``fx``) by ``m`` RK4 steps into
    ``xn`` (field ``fn``), with ``force = (forced, γ, Ω, phase at t_k)``, ``tol = (rtol,
    atol)`` and ``work`` five arrays of stages. Returns AMPLE (every error below 1/32 of its
    tolerance), ACCEPT, REJECT (an error above its tolerance) or NONFINITE (a state became
    inf or NaN)."""
    ns = N_STATES
    forced, gamma, om, ph = force
    rtol, atol = tol
    k1, k2, k3, k4, xi = work
    h = dt / m
    outcome = AMPLE
    for i in range(ns):
        xn[i] = x[i]
        fn[i] = fx[i]
    for sub in range(m):
        f0 = 0.0
        fm = 0.0
        f1 = 0.0
        if forced:
            f0 = gamma * math.cos(ph + om * (sub * h))
            fm = gamma * math.cos(ph + om * ((sub + 0.5) * h))
            f1 = gamma * math.cos(ph + om * ((sub + 1.0) * h))
        for i in range(ns):
            k1[i] = fn[i] + evec[i] * u + bvec[i] * f0
            xi[i] = xn[i] + 0.5 * h * k1[i]
        _field(xi, d, k2)
        for i in range(ns):
            k2[i] += evec[i] * u + bvec[i] * fm
            xi[i] = xn[i] + 0.5 * h * k2[i]
        _field(xi, d, k3)
        for i in range(ns):
            k3[i] += evec[i] * u + bvec[i] * fm
            xi[i] = xn[i] + h * k3[i]
        _field(xi, d, k4)
        for i in range(ns):
            k4[i] += evec[i] * u + bvec[i] * f1
            xi[i] = xn[i]  # the step's start, for the tolerance
            xn[i] = xn[i] + h * (k1[i] + 2.0 * k2[i] + 2.0 * k3[i] + k4[i]) / 6.0
        _field(xn, d, fn)
        for i in range(ns):
            if not math.isfinite(xn[i]):
                return NONFINITE
            # embedded 3rd-order solution: e = h (k4 - k5) / 6, k5 = f(x_{n+1}) + inputs
            err = abs(h * (k4[i] - (fn[i] + evec[i] * u + bvec[i] * f1)) / 6.0)
            tol = (rtol * max(abs(xi[i]), abs(xn[i]), xscale[i]) + atol) / m
            if not err <= tol:  # NaN or inf errors too
                outcome = REJECT
            elif outcome == AMPLE and err * 32.0 > tol:
                outcome = ACCEPT
    return outcome


@_njit
def run_block(p, r, bvec, evec, state, steps, flags, reals, out_idx, noise, tv, env, outs):
    """Advance the rig by ``noise.shape[0]`` samples (see the module docstring).

    ``state = (x, yprev, dfilt, xscale)`` is updated in place; ``steps = [m, m_min, m_max,
    peak, rejected]`` (int64) carries the RK4 steps per interval; ``flags`` (int64) and
    ``reals`` (float64) hold the settings named below, ``env = (lo, hi)`` the envelope of
    the states and ``outs = (Y, YD, U, REF, XS)`` receive the samples. Returns
    ``(uprev, n_done, trip_code, trip_index, trip_value)``: ``n_done < n`` when the
    safety gate tripped at sample ``n_done`` (rows from there on are not written).
    """
    x, yprev, dfilt, xscale = state
    env_lo, env_hi = env
    Y, YD, U, REF, XS = outs
    forced, tkind, s1, s1d = flags[0] != 0, flags[1], flags[2], flags[3] != 0
    s2, s2d, deriv_state, record = flags[4], flags[5] != 0, flags[6] != 0, flags[7] != 0
    uprev, gamma, om, psi, theta0 = reals[0], reals[1], reals[2], reals[3], reals[4]
    kp, kd, ctrl_on, umax, afilt = reals[5], reals[6], reals[7], reals[8], reals[9]
    alpha, dt, rtol, atol, env_umax = reals[10], reals[11], reals[12], reals[13], reals[14]
    n = noise.shape[0]
    ns = N_STATES
    no = out_idx.shape[0]
    d = _prepare(p, r, np.empty(N_COEF))
    fx = np.empty(ns)
    xn = np.empty(ns)
    fn = np.empty(ns)
    k1 = np.empty(ns)
    k2 = np.empty(ns)
    k3 = np.empty(ns)
    k4 = np.empty(ns)
    xi = np.empty(ns)
    work = (k1, k2, k3, k4, xi)
    y = np.empty(no)
    yd = np.empty(no)
    _field(x, d, fx)
    for k in range(n):
        theta = theta0 + om * (k * dt)
        if record:  # the true state at t_k, when y_k is measured
            for i in range(ns):
                XS[k, i] = x[i]
        for i in range(ns):  # the safety gate on the true state
            if not (env_lo[i] <= x[i] <= env_hi[i]):
                return uprev, k, TRIP_STATE, i, x[i]
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
        if not math.isfinite(u):
            return uprev, k, TRIP_SIGNAL, -1, u
        if abs(u) > env_umax:
            return uprev, k, TRIP_CONTROL, -1, u
        if u > umax:
            u = umax
        elif u < -umax:
            u = -umax
        # zero-order hold over [t_k, t_k + dt): m RK4 steps, m doubled until accurate
        while True:
            force = (forced, gamma, om, ph)
            outcome = _interval(
                x, fx, xn, fn, d, bvec, evec, u, force, dt, steps[0], (rtol, atol), xscale, work
            )
            if outcome <= ACCEPT:
                break
            if steps[0] >= steps[2]:
                code = TRIP_ACCURACY if outcome == REJECT else TRIP_NONFINITE
                return uprev, k, code, -1, float(steps[0])
            steps[0] = min(2 * steps[0], steps[2])
            steps[4] += 1
        steps[3] = max(steps[3], steps[0])
        if outcome == AMPLE and steps[0] > steps[1]:
            steps[0] = max(steps[0] // 2, steps[1])
        for i in range(ns):
            x[i] = xn[i]
            fx[i] = fn[i]
            xscale[i] = max(xscale[i], abs(x[i]))
        for i in range(no):
            Y[k, i] = y[i]
            YD[k, i] = yd[i]
            yprev[i] = y[i]
        U[k] = u
        REF[k] = ref
        uprev = u
    return uprev, n, TRIP_NONE, -1, 0.0

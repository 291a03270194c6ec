"""Stage 1 of the mechanistic identification: the linear stage on a free decay (§4.3.1).

The parameters of the linearisation are identified from a free decay by prediction-error
identification (:class:`~bifid.identify.LinearPEM`), from the release of the
record (or a given time) to its end.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from bifid.errors import BifidInputError
from bifid.identify.mechanistic._linear_pem import LinearPEM
from bifid.systems import System

__all__ = ["free_decay_arrays", "linear_stage", "release_index"]


def release_index(y: np.ndarray) -> int:
    """Sample at which a free decay is released: the latest of the outputs' largest excursions.

    After release a free decay can only lose energy, so the largest excursion of each output
    comes after the excitation ends; starting the fit at the latest of them drops the part
    of the record where the rig was still being excited.
    """
    y = np.asarray(y, dtype=float)
    if y.ndim == 1:
        y = y[:, None]
    rest = np.median(y[-max(1, y.shape[0] // 4) :], axis=0)
    return int(max(int(np.argmax(np.abs(y[:, c] - rest[c]))) for c in range(y.shape[1])))


def free_decay_arrays(fd: Any) -> tuple[np.ndarray, float]:
    """``(y, sample_rate)`` of a free decay given as such a pair or as a
    :class:`bifid.data.FreeDecay` (columns heave, pitch)."""
    if isinstance(fd, tuple) and len(fd) == 2:
        y, fs = fd
        return np.asarray(y, dtype=float), float(fs)
    if hasattr(fd, "heave") and hasattr(fd, "pitch"):
        return np.column_stack([fd.heave, fd.pitch]), float(fd.sample_rate)
    raise BifidInputError(
        "free_decay must be (y, sample_rate) with y of shape (n_samples, n_outputs), or a "
        "bifid.data.FreeDecay."
    )


def linear_stage(
    system: System,
    p: np.ndarray,
    param: str,
    free_decay: Any,
    *,
    free: Sequence[str],
    outputs: Sequence[str],
    ratios: Mapping[str, str],
    options: Mapping[str, Any],
    param_value: float,
    start: str | float,
    stop: float | None,
) -> tuple[np.ndarray, LinearPEM, dict[str, Any]]:
    """Identify ``free`` (and the ``ratios``-tied parameters) from a free decay.

    The record runs from ``start`` ("release": :func:`release_index`, or seconds) to
    ``stop`` (seconds, default the end); the bifurcation parameter is ``param_value``
    during the decay.

    Returns
    -------
    p : ndarray
        The parameter vector with the identified values.
    pem : LinearPEM
    summary : dict
    """
    if not free:
        raise BifidInputError("the linear stage needs linear_free (parameters to identify).")
    y, fs = free_decay_arrays(free_decay)
    i0 = release_index(y) if start == "release" else round(float(start) * fs)
    i1 = y.shape[0] if stop is None else round(stop * fs)
    if not 0 <= i0 < i1 - 20:
        raise BifidInputError(
            f"the free-decay window [{i0 / fs:g}, {i1 / fs:g}] s is empty or too short."
        )
    initial = {**{k: float(v) for k, v in system.param_dict(p).items()}, param: param_value}
    pem = LinearPEM(
        system,
        tuple(free),
        tuple(outputs),
        params=initial,
        ratios=dict(ratios),
        **{"decimate": 10, **dict(options)},
    )
    pem.fit(y[i0:i1], fs)
    p = np.asarray(p, dtype=float).copy()
    for nm in (*free, *ratios):
        p[system.index(nm)] = pem.p_[system.index(nm)]
    summary = {
        "parameters": dict(pem.params_),
        "stderr": pem.stderr_,
        "window_s": [i0 / fs, i1 / fs],
        "tied": pem.tied_,
        "fit_percent": pem.fit_percent_,
        "rmse": pem.rmse_,
        "modes": pem.modal_summary(),
    }
    return p, pem, summary

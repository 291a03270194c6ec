"""Record types: one measured (or computed) periodic response each.

A record holds the sampled signals of one steady periodic orbit, the parameter(s) it was
measured at, the control signal that held it, and its stability label when known. Records
are validated when built, so a dataset built from records is valid by construction.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping
from typing import Any

import numpy as np

from bifid.errors import BifidInputError

__all__ = ["ForcedRecord", "LCORecord"]

ExtraValue = float | int | str


def _finite_scalar(
    name: str, value: Any, *, positive: bool = False, allow_nan: bool = False
) -> float:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a real number, got {value!r}.") from None
    if arr.shape not in ((), (1,)):
        raise BifidInputError(f"{name} must be a scalar, got an array of shape {arr.shape}.")
    v = float(arr.reshape(()))
    if math.isnan(v) and allow_nan:
        return v
    if not math.isfinite(v):
        raise BifidInputError(f"{name} must be finite, got {v!r}.")
    if positive and v <= 0:
        raise BifidInputError(f"{name} must be > 0, got {v!r}.")
    return v


def _signals(value: Any) -> np.ndarray:
    try:
        arr = np.array(value, dtype=float)
    except (TypeError, ValueError):
        raise BifidInputError("signals must be a numeric array (n_samples, n_signals).") from None
    if arr.ndim == 1:
        arr = arr[:, None]
    if arr.ndim != 2:
        raise BifidInputError(
            f"signals must have shape (n_samples, n_signals), got shape {arr.shape}."
        )
    if arr.shape[0] < 1 or arr.shape[1] < 1:
        raise BifidInputError(
            f"signals must hold at least one sample of one signal, got {arr.shape}."
        )
    if not np.all(np.isfinite(arr)):
        bad = int(np.size(arr) - np.count_nonzero(np.isfinite(arr)))
        raise BifidInputError(
            f"signals contain {bad} NaN/inf values; clean or trim them before building a record."
        )
    return arr


def _series(name: str, value: Any, n: int, *, allow_nan: bool) -> np.ndarray | None:
    if value is None:
        return None
    try:
        arr = np.array(value, dtype=float).reshape(-1) if np.ndim(value) <= 1 else None
    except (TypeError, ValueError):
        raise BifidInputError(f"{name} must be a numeric 1-D array of length {n}.") from None
    if arr is None:
        raise BifidInputError(f"{name} must be 1-D of length {n}, got shape {np.shape(value)}.")
    if arr.shape != (n,):
        raise BifidInputError(
            f"{name} must have one value per sample ({n}), got {arr.shape[0]} values."
        )
    if allow_nan:
        if np.any(np.isinf(arr)):
            raise BifidInputError(f"{name} contains inf values.")
    elif not np.all(np.isfinite(arr)):
        raise BifidInputError(f"{name} contains NaN/inf values.")
    return arr


def _stable(value: Any) -> bool | None:
    if value is None:
        return None
    if isinstance(value, (bool, np.bool_)):
        return bool(value)
    if isinstance(value, (int, np.integer)) and int(value) in (0, 1):
        return bool(value)
    if isinstance(value, (int, np.integer)) and int(value) == -1:
        return None
    raise BifidInputError(f"stable must be True, False or None (unknown), got {value!r}.")


def _extra(value: Mapping[str, Any] | None) -> dict[str, ExtraValue]:
    if value is None:
        return {}
    if not isinstance(value, Mapping):
        raise BifidInputError(f"extra must be a dict of scalars, got {type(value).__name__}.")
    out: dict[str, ExtraValue] = {}
    for k, v in value.items():
        if not isinstance(k, str) or not k.isidentifier():
            raise BifidInputError(
                f"extra keys must be identifiers (letters, digits, _), got {k!r}."
            )
        if isinstance(v, str):
            out[k] = str(v)
        elif isinstance(v, (bool, np.bool_)):
            out[k] = float(bool(v))
        else:
            try:
                out[k] = float(np.asarray(v, dtype=float).reshape(()))
            except (TypeError, ValueError):
                raise BifidInputError(
                    f"extra[{k!r}] must be a number or a string, got {type(v).__name__}."
                ) from None
    return out


class _Sampled:
    """Sample count and times of a record with ``signals`` sampled at ``sample_rate``."""

    signals: np.ndarray
    sample_rate: float

    @property
    def n_samples(self) -> int:
        """Number of samples."""
        return int(self.signals.shape[0])

    @property
    def time(self) -> np.ndarray:
        """Sample times ``k / sample_rate`` [s]."""
        return np.arange(self.n_samples) / self.sample_rate


@dataclasses.dataclass
class LCORecord(_Sampled):
    """One limit cycle of an autonomous system, sampled at a fixed parameter value.

    Parameters
    ----------
    param
        Value of the bifurcation parameter (e.g. wind speed U [m/s]).
    signals
        ``(n_samples, n_signals)`` measured outputs, centred (static offsets removed).
    sample_rate
        Sampling rate [Hz]; sample ``k`` is at ``t_k = k / sample_rate``.
    stable
        ``True``/``False`` when the stability is known, ``None`` otherwise.
    control
        ``(n_samples,)`` control signal (e.g. shaker force); ``None`` means no control (0).
    target
        ``(n_samples,)`` control target; ``None`` when there is none.
    frequency
        Angular frequency of the orbit [rad/s]; NaN when unknown.
    extra
        Further per-record scalars (numbers or strings), e.g. convergence errors.
    """

    param: float
    signals: np.ndarray
    sample_rate: float
    stable: bool | None = None
    control: np.ndarray | None = None
    target: np.ndarray | None = None
    frequency: float = float("nan")
    extra: dict[str, ExtraValue] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        self.param = _finite_scalar("param", self.param)
        self.signals = _signals(self.signals)
        self.sample_rate = _finite_scalar("sample_rate", self.sample_rate, positive=True)
        self.stable = _stable(self.stable)
        n = self.signals.shape[0]
        self.control = _series("control", self.control, n, allow_nan=False)
        self.target = _series("target", self.target, n, allow_nan=True)
        self.frequency = _finite_scalar("frequency", self.frequency, allow_nan=True)
        if not math.isnan(self.frequency) and self.frequency < 0:
            raise BifidInputError(f"frequency must be >= 0 rad/s, got {self.frequency!r}.")
        self.extra = _extra(self.extra)

    @property
    def amplitude(self) -> np.ndarray:
        """``max_t |x_s(t)|`` per signal (thesis eq. 6.5)."""
        return np.max(np.abs(self.signals), axis=0)


@dataclasses.dataclass
class ForcedRecord(_Sampled):
    """One steady periodic response of a harmonically forced system.

    Parameters
    ----------
    omega
        Forcing frequency [rad/s].
    forcing
        Forcing amplitude (units in the dataset attribute ``forcing_units``).
    signals
        ``(n_samples, n_signals)`` measured outputs.
    sample_rate
        Sampling rate [Hz].
    stable
        Stability label, ``None`` when unknown.
    force
        ``(n_samples,)`` measured forcing signal; ``None`` when not recorded.
    control, target
        As in :class:`LCORecord`.
    amplitude
        Amplitude of the observed signal; ``None`` → ``max_t |x_obs(t)|`` is computed by the
        dataset builder.
    phase
        Lag of the observed first harmonic behind the force [rad]; ``None`` → computed from
        ``force`` when present (:func:`bifid.signal.phase_lag`), NaN otherwise.
    curve
        Integer id of the S-curve / FRC / backbone this point belongs to.
    extra
        Further per-record scalars.
    """

    omega: float
    forcing: float
    signals: np.ndarray
    sample_rate: float
    stable: bool | None = None
    force: np.ndarray | None = None
    control: np.ndarray | None = None
    target: np.ndarray | None = None
    amplitude: float | None = None
    phase: float | None = None
    curve: int = 0
    extra: dict[str, ExtraValue] = dataclasses.field(default_factory=dict)

    def __post_init__(self) -> None:
        self.omega = _finite_scalar("omega", self.omega)
        if self.omega < 0:
            raise BifidInputError(f"omega must be >= 0 rad/s, got {self.omega!r}.")
        self.forcing = _finite_scalar("forcing", self.forcing)
        self.signals = _signals(self.signals)
        self.sample_rate = _finite_scalar("sample_rate", self.sample_rate, positive=True)
        self.stable = _stable(self.stable)
        n = self.signals.shape[0]
        self.force = _series("force", self.force, n, allow_nan=False)
        self.control = _series("control", self.control, n, allow_nan=False)
        self.target = _series("target", self.target, n, allow_nan=True)
        if self.amplitude is not None:
            self.amplitude = _finite_scalar("amplitude", self.amplitude)
            if self.amplitude < 0:
                raise BifidInputError(f"amplitude must be >= 0, got {self.amplitude!r}.")
        if self.phase is not None:
            self.phase = _finite_scalar("phase", self.phase, allow_nan=True)
        if isinstance(self.curve, (bool, np.bool_)) or not isinstance(
            self.curve, (int, np.integer)
        ):
            c = _finite_scalar("curve", self.curve)
            if c != int(c):
                raise BifidInputError(f"curve must be an integer id, got {self.curve!r}.")
            self.curve = int(c)
        self.curve = int(self.curve)
        self.extra = _extra(self.extra)

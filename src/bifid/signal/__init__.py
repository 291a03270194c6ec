"""Signals: Fourier series, amplitudes, frequencies and noise floors of sampled records
and of one-period grids — the one place bifid projects, measures and repairs a signal.

>>> import numpy as np
>>> from bifid.signal import estimate_frequency
>>> t = np.arange(2000) / 100.0
>>> round(estimate_frequency(np.sin(3.0 * t), 100.0, method="crossings"), 6)
3.0
"""

from bifid.signal._amplitude import (
    aligned_orbit_error,
    first_harmonic,
    max_abs,
    periodic_amplitude,
    phase_lag,
    spectral_tail,
)
from bifid.signal._frequency import band_noise, coefficient_noise, estimate_frequency
from bifid.signal._gaps import fill_gaps
from bifid.signal._series import (
    evaluate_fourier,
    evaluate_series,
    fourier_basis,
    fourier_coefficients,
    fourier_fit,
    fourier_fit_columns,
    fourier_project,
    fourier_project_batch,
    fourier_project_segments,
    polar_project,
    uniform_basis,
    usable_harmonics,
    whole_periods,
)

__all__ = [
    "aligned_orbit_error",
    "band_noise",
    "coefficient_noise",
    "estimate_frequency",
    "evaluate_fourier",
    "evaluate_series",
    "fill_gaps",
    "first_harmonic",
    "fourier_basis",
    "fourier_coefficients",
    "fourier_fit",
    "fourier_fit_columns",
    "fourier_project",
    "fourier_project_batch",
    "fourier_project_segments",
    "max_abs",
    "periodic_amplitude",
    "phase_lag",
    "polar_project",
    "spectral_tail",
    "uniform_basis",
    "usable_harmonics",
    "whole_periods",
]

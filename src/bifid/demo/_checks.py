"""The tolerances a demo's prediction must meet against the ground truth (its checks)."""

from __future__ import annotations

#: flutter demo: speeds in m/s, the rest relative
FLUTTER_CHECKS = {
    "hopf_U": 0.1,
    "fold_U": 0.2,
    "amplitude_rel": 0.06,
    "frequency_rel": 0.02,
    "series_rel": 0.10,
    # mechanistic stage, for noise-free data
    "mechanistic_params_rel": 0.02,
    "mechanistic_U": 0.05,
}

#: forced demo: relative errors of the predicted FRC peaks, fold frequencies and backbone
FORCED_CHECKS = {"peak_rel": 0.04, "fold_omega_rel": 0.002, "backbone_rel": 0.02}

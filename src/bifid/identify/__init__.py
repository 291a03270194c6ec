"""Identification of models from bifurcation data (thesis ch. 4–6).

Submodules are imported lazily so that one capability missing or failing to import never
breaks the others: ``bifid.identify.kernels`` (GP / kernel ridge regression),
``bifid.identify.forced_kernel`` (ch. 6), ``bifid.identify.hopf_hybrid`` (ch. 5),
``bifid.identify.mechanistic`` and ``bifid.identify.linear_pem`` (ch. 4).
"""

from __future__ import annotations

import importlib
from typing import Any

# public name -> submodule that defines it
_LAZY = {
    "GPRegressor": "bifid.identify.kernels",
    "HyperBounds": "bifid.identify.kernels",
    "ForcedKernelModel": "bifid.identify.forced_kernel",
    "band_coverage": "bifid.identify.forced_kernel",
}


def __getattr__(name: str) -> Any:
    module = _LAZY.get(name)
    if module is None:
        raise AttributeError(f"module 'bifid.identify' has no attribute {name!r}")
    return getattr(importlib.import_module(module), name)


def __dir__() -> list[str]:
    return sorted(list(globals()) + list(_LAZY))

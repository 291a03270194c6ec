"""The demos behind ``bifid demo``: a whole virtual experiment, identified and checked.

- :func:`run_flutter_demo`: virtual PP-CBC campaign on the flutter rig → hybrid model
  (thesis ch. 5) → predicted diagram, portraits, time series → compared with continuation.
- :func:`run_forced_demo`: virtual CBC S-curves on ``shaw_pierre`` → kernel model (ch. 6)
  → FRCs at untrained forcing with uncertainty bands and the backbone → compared with
  continuation.

Each writes ``report.html``, PNG figures, the dataset and the model into its directory and
reuses, on a second run, every stage whose settings did not change (:class:`StageCache`,
keyed by :func:`settings_key` of the stage's settings).
"""

from bifid.demo._cache import StageCache, settings_key
from bifid.demo._flutter import FlutterDemoSettings, run_flutter_demo
from bifid.demo._forced import ForcedDemoSettings, run_forced_demo

__all__ = [
    "FlutterDemoSettings",
    "ForcedDemoSettings",
    "StageCache",
    "run_flutter_demo",
    "run_forced_demo",
    "settings_key",
]

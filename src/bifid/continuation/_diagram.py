"""The one result type of bifid: a :class:`Diagram` of branches with their special points.

Every producer returns a Diagram — continuation of a system, a CBC campaign on a rig, and
every fitted model's ``predict_diagram`` — so that any two can be compared point by point,
saved to and loaded from netCDF, and printed by the CLI through one :meth:`Diagram.to_json`,
which *is* the JSON contract of ``DESIGN.md``:

================  =========================================================================
``kind``          keys
================  =========================================================================
``bifurcation``   ``hopf``, ``folds`` (of equilibria), ``cycle_folds``, ``secondary``,
                  ``orbits`` (``points`` for a measured diagram)
``frc``           ``points`` (``omega``), ``folds``, ``peak``
``scurve``        ``points`` (``forcing``), ``folds``
``backbone``      ``points`` (``amplitude``, ``omega``)
================  =========================================================================

and on every diagram ``ends``, ``candidates``, ``complete``, ``status``, ``warnings``,
``settings`` (provenance), ``level`` (predictions with intervals) and ``failures``
(measured points that could not be taken, with their reason).
"""

from __future__ import annotations

import json
import math
import os
from collections.abc import Iterable, Sequence
from dataclasses import asdict, dataclass, field
from typing import Any, Literal

import numpy as np

from bifid.continuation._branch import INCOMPLETE, Branch, Candidate, SpecialPoint
from bifid.continuation._options import ContinuationOptions
from bifid.errors import BifidInputError
from bifid.io import atomic_write_netcdf

DiagramKind = Literal["bifurcation", "frc", "scurve", "backbone"]

#: JSON name of the continuation parameter of each kind of diagram
PARAM_KEYS: dict[str, str] = {
    "bifurcation": "param",
    "frc": "omega",
    "scurve": "forcing",
    "backbone": "amplitude",
}

#: per-point scalar quantities reported for each branch kind (``Branch.meta["report"]``
#: overrides)
_POINT_KEYS: dict[str, tuple[str, ...]] = {
    "equilibrium": (),
    "periodic": ("period", "floquet_max"),
    "forced": ("phase",),
    "backbone": ("omega", "forcing"),
    "measured": ("frequency", "phase", "control_rms"),
}

#: data of special points reported for each kind (others stay in ``SpecialPoint.data``)
_SPECIAL_KEYS: dict[str, tuple[str, ...]] = {
    "hopf": ("omega", "lyapunov", "criticality"),
    "fold": ("amplitude",),
    "cycle_fold": ("period", "amplitude"),
    "peak": ("amplitude",),
    "period_doubling": (),
    "torus": (),
    "branch_point": (),
}
_SECONDARY = ("period_doubling", "torus", "branch_point")


def _clean(v: Any) -> Any:
    """Plain JSON values: numpy scalars and arrays converted, NaN / inf as None."""
    if isinstance(v, dict):
        return {str(k): _clean(x) for k, x in v.items()}
    if isinstance(v, (list, tuple)):
        return [_clean(x) for x in v]
    if isinstance(v, np.ndarray):
        return _clean(v.tolist())
    if isinstance(v, (bool, np.bool_)):
        return bool(v)
    if isinstance(v, np.integer):
        return int(v)
    if isinstance(v, (float, np.floating)):
        f = float(v)
        return f if math.isfinite(f) else None
    if isinstance(v, complex):
        return [_clean(v.real), _clean(v.imag)]
    return v


def _by_signal(values: Any, signals: Sequence[str]) -> Any:
    """A per-signal array as ``{signal: value}``; a scalar stays a scalar."""
    arr = np.asarray(values)
    if arr.ndim == 0:
        return float(arr)
    if signals and arr.shape[-1] == len(signals):
        return {s: _clean(arr[..., k]) for k, s in enumerate(signals)}
    return _clean(arr)


@dataclass
class Diagram:
    """Branches with their special points, units and provenance.

    Attributes
    ----------
    kind : {"bifurcation", "frc", "scurve", "backbone"}
        The question the diagram answers.
    system : str
        System or model it belongs to.
    param : str
        Name of the continuation parameter (``Omega`` for an FRC, ``F`` for an S-curve).
    branches : list of Branch
    source : str
        ``"continuation"``, ``"measurement"`` (a CBC campaign) or the model type of a
        prediction.
    units : dict of str
        Units of the parameter and of the signals, by name.
    settings : dict
        How the diagram was produced (provenance; the CLI's ``settings``).
    candidates : list of Candidate
        Possible special points that could not be located and verified.
    failures : list of dict
        Points a measurement could not take, each with ``reason`` (and where it was).
    warnings : list of str
    level : float, optional
        Confidence level of the intervals carried by the branches and special points.
    info : dict
        Further top-level JSON entries (``observed``, ``linear_frequency``, ...).
    """

    kind: DiagramKind
    system: str
    param: str
    branches: list[Branch]
    source: str = "continuation"
    units: dict[str, str] = field(default_factory=dict)
    settings: dict[str, Any] = field(default_factory=dict)
    candidates: list[Candidate] = field(default_factory=list)
    failures: list[dict[str, Any]] = field(default_factory=list)
    warnings: list[str] = field(default_factory=list)
    level: float | None = None
    info: dict[str, Any] = field(default_factory=dict)

    def __post_init__(self) -> None:
        if self.kind not in PARAM_KEYS:
            raise BifidInputError(
                f"Diagram kind must be one of {', '.join(PARAM_KEYS)}; got {self.kind!r}."
            )
        if self.level is not None and not 0.0 < float(self.level) < 1.0:
            raise BifidInputError(f"level must lie in (0, 1), got {self.level!r}.")

    # ------------------------------------------------------------------ queries
    @property
    def complete(self) -> bool:
        """False when a branch was cut short or a measured point failed."""
        return all(b.complete for b in self.branches) and not self.failures

    @property
    def status(self) -> str:
        """``ok``, or why the diagram is incomplete (the first branch's reason, or
        ``incomplete`` for failed measurements)."""
        for b in self.branches:
            if b.status in INCOMPLETE:
                return b.status
        return "incomplete" if self.failures else "ok"

    @property
    def message(self) -> str:
        """The first incomplete branch's message (empty when complete)."""
        for b in self.branches:
            if b.status in INCOMPLETE:
                return b.message
        if self.failures:
            return f"{len(self.failures)} point(s) failed: {self.failures[0].get('reason', '')}"
        return ""

    def special(self, kind: str) -> list[SpecialPoint]:
        """Located special points of one kind on all branches, in branch order."""
        return [sp for b in self.branches for sp in b.special(kind)]

    def of_kind(self, kind: str) -> list[Branch]:
        """The branches of one kind (``equilibrium``, ``periodic``, ``forced``, ...)."""
        return [b for b in self.branches if b.kind == kind]

    @property
    def param_key(self) -> str:
        return PARAM_KEYS[self.kind]

    # --------------------------------------------------------------------- JSON
    def to_json(self) -> dict[str, Any]:
        """The JSON object the CLI prints (``DESIGN.md``, public contract)."""
        out: dict[str, Any] = {
            "system": self.system,
            "param": self.param,
            "kind": self.kind,
            "source": self.source,
        }
        out.update(self.info)
        if self.kind == "bifurcation":
            out["hopf"] = self._specials_json(("hopf",))
            out["folds"] = self._specials_json(("fold",), self.of_kind("equilibrium"))
            out["cycle_folds"] = self._specials_json(("cycle_fold",))
            out["secondary"] = self._specials_json(_SECONDARY)
            key = "points" if self.source == "measurement" else "orbits"
            out[key] = [
                pt for b in self.branches if b.kind != "equilibrium" for pt in self._points_json(b)
            ]
        else:
            out["points"] = [pt for b in self.branches for pt in self._points_json(b)]
            if self.kind in ("frc", "scurve"):
                out["folds"] = self._specials_json(("fold",))
                out["secondary"] = self._specials_json(_SECONDARY)
            if self.kind == "frc":
                out["peak"] = self._peak_json()
        out["ends"] = [
            {
                "branch": i,
                "param": float(b.params[-1]) if len(b) else None,
                "reason": b.status,
                "message": b.message,
            }
            for i, b in enumerate(self.branches)
        ]
        out["candidates"] = [
            {"kind": c.kind, "bracket": list(c.bracket), "reason": c.reason, "branch": i}
            for i, b in enumerate(self.branches)
            for c in b.candidates
        ]
        out["candidates"] += [
            {"kind": c.kind, "bracket": list(c.bracket), "reason": c.reason, "branch": c.branch}
            for c in self.candidates
        ]
        if self.failures:
            out["failures"] = list(self.failures)
        if self.level is not None:
            out["level"] = float(self.level)
        out["complete"] = self.complete
        out["status"] = self.status
        if not self.complete:
            out["message"] = self.message
        out["warnings"] = list(self.warnings)
        out["settings"] = dict(self.settings)
        return _clean(out)

    def _branch_index(self, b: Branch) -> int:
        """Position of ``b`` in ``branches`` (the ``branch`` of ``ends`` and ``candidates``)."""
        return next(i for i, x in enumerate(self.branches) if x is b)

    def _specials_json(
        self, kinds: tuple[str, ...], branches: list[Branch] | None = None
    ) -> list[dict[str, Any]]:
        """The JSON of the special points of ``kinds`` on ``branches`` (default: all), in
        branch order."""
        return [
            self._special_json(sp, b)
            for b in (self.branches if branches is None else branches)
            for sp in b.special_points
            if sp.kind in kinds
        ]

    def _special_json(self, sp: SpecialPoint, b: Branch) -> dict[str, Any]:
        key = "param" if self.kind == "bifurcation" else self.param_key
        d: dict[str, Any] = {}
        if sp.kind in _SECONDARY:
            d["kind"] = sp.kind
        d[key] = sp.param
        d["branch"] = self._branch_index(b)
        if sp.kind == "fold" and b.kind == "equilibrium":
            d["state"] = _by_signal(np.asarray(sp.solution)[: len(b.signals)], b.signals)
        for k in _SPECIAL_KEYS.get(sp.kind, ()):
            if k in sp.data:
                v = sp.data[k]
                d[k] = _by_signal(v, b.signals) if k == "amplitude" else v
        d["precision"] = sp.precision
        if sp.verification:
            d["verification"] = dict(sp.verification)
        for k, (lo, hi) in sp.intervals.items():
            name = key if k == "param" else k
            d[f"{name}_interval"] = _interval_json(lo, hi, b.signals)
        return d

    def _points_json(self, b: Branch) -> list[dict[str, Any]]:
        key = self.param_key if self.kind != "backbone" else None
        amp_key = "observed_amplitude" if "observed_amplitude" in b.data else "amplitude"
        report = tuple(b.meta.get("report", _POINT_KEYS.get(b.kind, ())))
        n_mesh = b.data.get("n_mesh")
        out = []
        for i in range(len(b)):
            d: dict[str, Any] = {}
            if key is not None:
                d[key] = b.params[i]
            if amp_key in b.data:
                d["amplitude"] = _by_signal(b.data[amp_key][i], b.signals)
            if "amplitude_centred" in b.data:
                d["amplitude_centred"] = _by_signal(b.data["amplitude_centred"][i], b.signals)
            if "offset" in b.data:
                d["offset"] = _by_signal(b.data["offset"][i], b.signals)
            for k in report:
                if k in b.data and k != key:
                    d[k] = b.data[k][i]
            d["stable"] = None if b.stable is None else _stable_json(b.stable[i])
            d["branch"] = self._branch_index(b)
            if n_mesh is not None:
                d["n_mesh"] = int(n_mesh[i])
            elif "n_mesh" in b.meta and b.kind in ("periodic", "forced", "backbone"):
                d["n_mesh"] = int(b.meta["n_mesh"])
            if b.verification:
                d["verification"] = {k: v[i] for k, v in b.verification.items()}
            for k, (lo, hi) in b.intervals.items():
                name = "amplitude" if k == amp_key else k
                d[f"{name}_interval"] = _interval_json(lo[i], hi[i], b.signals)
            out.append(d)
        return out

    def _peak_json(self) -> dict[str, Any] | None:
        peaks = self.special("peak")
        if peaks:
            best = max(peaks, key=lambda sp: float(np.max(sp.data.get("amplitude", -np.inf))))
            owner = next(b for b in self.branches if best in b.special_points)
            return self._special_json(best, owner)
        best_val, best = -np.inf, None
        for b in self.branches:
            amp = b.data.get("observed_amplitude", b.data.get("amplitude"))
            if amp is None or len(b) == 0:
                continue
            amp = np.asarray(amp, dtype=float)
            k = int(np.nanargmax(amp if amp.ndim == 1 else amp[:, 0]))
            v = float(amp[k] if amp.ndim == 1 else amp[k, 0])
            if v > best_val:
                best_val, best = v, {self.param_key: float(b.params[k]), "amplitude": v}
        return best

    # ------------------------------------------------------------------ netCDF
    def save(self, path: str | os.PathLike[str]) -> None:
        """Write the diagram to a netCDF-4 file (one group per branch), atomically."""
        atomic_write_netcdf(self._to_datatree(), path)

    @classmethod
    def load(cls, path: str | os.PathLike[str]) -> Diagram:
        """Read a diagram written by :meth:`save`.

        Raises
        ------
        BifidInputError
            If the file is not a bifid diagram.
        """
        import xarray as xr

        try:
            tree = xr.open_datatree(path, engine="h5netcdf")
        except (OSError, ValueError) as exc:
            raise BifidInputError(f"{path}: not a readable netCDF file ({exc}).") from None
        with tree:
            tree = tree.load()
        attrs = dict(tree.attrs)
        if attrs.get("bifid_type") != "diagram":
            raise BifidInputError(f"{path} is not a bifid diagram (no bifid_type='diagram').")
        branches = [
            _branch_from_dataset(tree[f"branch_{i}"].to_dataset())
            for i in range(int(attrs["n_branches"]))
        ]
        level = attrs.get("level")
        return cls(
            kind=str(attrs["kind"]),
            system=str(attrs["system"]),
            param=str(attrs["param"]),
            branches=branches,
            source=str(attrs.get("source", "continuation")),
            units=json.loads(attrs.get("units", "{}")),
            settings=json.loads(attrs.get("settings", "{}")),
            candidates=[
                Candidate(c["kind"], tuple(c["bracket"]), c["reason"], c["branch"])
                for c in json.loads(attrs.get("candidates", "[]"))
            ],
            failures=json.loads(attrs.get("failures", "[]")),
            warnings=json.loads(attrs.get("warnings", "[]")),
            level=None
            if level is None or (isinstance(level, float) and math.isnan(level))
            else float(level),
            info=json.loads(attrs.get("info", "{}")),
        )

    def _to_datatree(self):
        import xarray as xr

        attrs = {
            "bifid_type": "diagram",
            "kind": self.kind,
            "system": self.system,
            "param": self.param,
            "source": self.source,
            "n_branches": len(self.branches),
            "units": json.dumps(_clean(self.units)),
            "settings": json.dumps(_clean(self.settings)),
            "candidates": json.dumps(_clean([asdict(c) for c in self.candidates])),
            "failures": json.dumps(_clean(self.failures)),
            "warnings": json.dumps(list(self.warnings)),
            "info": json.dumps(_clean(self.info)),
            "level": math.nan if self.level is None else float(self.level),
        }
        children = {
            f"branch_{i}": xr.DataTree(_branch_to_dataset(b)) for i, b in enumerate(self.branches)
        }
        return xr.DataTree(xr.Dataset(attrs=attrs), children=children)


def _stable_json(v: Any) -> bool | None:
    if isinstance(v, (float, np.floating)) and math.isnan(v):
        return None
    return bool(v)


def _interval_json(lo: Any, hi: Any, signals: Sequence[str]) -> Any:
    lo, hi = np.asarray(lo, dtype=float), np.asarray(hi, dtype=float)
    if lo.ndim == 0:
        return [_clean(float(lo)), _clean(float(hi))]
    if signals and lo.shape[-1] == len(signals):
        return {s: [_clean(float(lo[k])), _clean(float(hi[k]))] for k, s in enumerate(signals)}
    return [_clean(lo), _clean(hi)]


# ------------------------------------------------------------- branch <-> Dataset
def _put(variables: dict, name: str, value: Any) -> None:
    """Store an array under ``name`` with dims ``point`` first; complex as two parts."""
    arr = np.asarray(value)
    dims = ("point", *(f"{name}_dim{k}" for k in range(1, arr.ndim)))
    if np.iscomplexobj(arr):
        variables[f"{name}__re"] = (dims, arr.real)
        variables[f"{name}__im"] = (dims, arr.imag)
    else:
        variables[name] = (dims, arr)


def _take(ds: Any, prefix: str) -> dict[str, np.ndarray]:
    out: dict[str, np.ndarray] = {}
    for name in ds.data_vars:
        if not name.startswith(prefix):
            continue
        key = name[len(prefix) :]
        if key.endswith("__im"):
            continue
        if key.endswith("__re"):
            base = key[:-4]
            out[base] = ds[name].values + 1j * ds[f"{prefix}{base}__im"].values
        else:
            out[key] = ds[name].values
    return out


def _branch_to_dataset(b: Branch):
    import xarray as xr

    v: dict[str, Any] = {}
    _put(v, "params", b.params)
    _put(v, "solutions", np.asarray(b.solutions).reshape(len(b), -1))
    stable = np.asarray(b.stable, dtype=float) if b.stable is not None else np.full(len(b), np.nan)
    _put(v, "stable", stable)
    for k, a in b.data.items():
        if np.asarray(a).shape[:1] == (len(b),) and np.asarray(a).dtype.kind in "fciub":
            _put(v, f"data_{k}", a)
    for k, a in b.verification.items():
        _put(v, f"verification_{k}", a)
    for k, (lo, hi) in b.intervals.items():
        _put(v, f"lo_{k}", lo)
        _put(v, f"hi_{k}", hi)
    specials = []
    for j, sp in enumerate(b.special_points):
        sol = np.asarray(sp.solution, dtype=float).ravel()
        v[f"special{j}_solution"] = ((f"special{j}_n",), sol)
        data = {k: x for k, x in sp.data.items() if k not in ("eigenvector", "p")}
        specials.append(
            {
                "kind": sp.kind,
                "param": sp.param,
                "index": sp.index,
                "bracket": list(sp.bracket),
                "precision": sp.precision,
                "status": sp.status,
                "data": _clean(data),
                "verification": _clean(sp.verification),
                "intervals": _clean(sp.intervals),
            }
        )
    attrs = {
        "kind": b.kind,
        "system": b.system,
        "param": b.param,
        "status": b.status,
        "message": b.message,
        "signals": json.dumps(list(b.signals)),
        "meta": json.dumps(_clean(b.meta)),
        "specials": json.dumps(specials),
        "options": json.dumps(_clean(asdict(b.options)) if b.options else None),
        "candidates": json.dumps(_clean([asdict(c) for c in b.candidates])),
    }
    v["p"] = (("parameter",), np.asarray(b.p, dtype=float).ravel())
    return xr.Dataset(v, attrs=attrs)


def _branch_from_dataset(ds: Any) -> Branch:
    a = ds.attrs
    n = ds.sizes.get("point", 0)
    specials = []
    for j, s in enumerate(json.loads(a["specials"])):
        specials.append(
            SpecialPoint(
                kind=s["kind"],
                param=float(s["param"]),
                index=int(s["index"]),
                bracket=tuple(s["bracket"]),
                solution=ds[f"special{j}_solution"].values,
                precision=math.nan if s["precision"] is None else float(s["precision"]),
                status=s["status"],
                data=s["data"],
                verification=s["verification"],
                intervals={k: tuple(x) for k, x in s["intervals"].items()},
            )
        )
    stable = ds["stable"].values if "stable" in ds else np.full(n, np.nan)
    if not np.any(np.isnan(stable)):
        stable = stable.astype(bool)
    lo, hi = _take(ds, "lo_"), _take(ds, "hi_")
    opts = json.loads(a.get("options", "null"))
    return Branch(
        kind=a["kind"],
        system=a["system"],
        param=a["param"],
        params=ds["params"].values,
        solutions=ds["solutions"].values,
        stable=stable,
        special_points=specials,
        data=_take(ds, "data_"),
        p=ds["p"].values,
        status=a["status"],
        message=a["message"],
        # non-finite options (the default bounds) were written as null: their defaults
        options=ContinuationOptions(**{k: v for k, v in opts.items() if v is not None})
        if opts
        else None,
        meta=json.loads(a["meta"]),
        signals=tuple(json.loads(a["signals"])),
        verification=_take(ds, "verification_"),
        intervals={k: (lo[k], hi[k]) for k in lo},
        candidates=[
            Candidate(c["kind"], tuple(c["bracket"]), c["reason"], c["branch"])
            for c in json.loads(a.get("candidates", "[]"))
        ],
    )


def diagram_of(kind: DiagramKind, branches: Iterable[Branch], **kw: Any) -> Diagram:
    """A :class:`Diagram` of ``branches`` named after their system and parameter."""
    branches = list(branches)
    if not branches:
        raise BifidInputError("a diagram needs at least one branch.")
    return Diagram(
        kind=kind, system=branches[0].system, param=branches[0].param, branches=branches, **kw
    )

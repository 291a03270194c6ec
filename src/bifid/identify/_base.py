"""The estimator contract every identification method implements.

A fitted model answers the questions continuation answers for a system, with the same
result types, so the three methods of the thesis (chapters 4–6) are used, compared, saved
and served by one piece of code:

==========================  =================================================================
``__init__(**hyper)``       hyperparameters only (scikit-learn discipline)
``fit(dataset, **extra)``   validates, sets fitted attributes ending in ``_``, returns self;
                            ``dataset``: a path, an ``xarray.Dataset`` of bifid's schema, or
                            a list of them; further data by name (``free_decay=``)
``predict_diagram(...)``    a :class:`~bifid.continuation.Diagram` (``bifurcation``, ``frc``,
                            ``scurve`` or ``backbone``) with the option names of the CLI
``predict_orbit(...)``      one period of every signal on one periodic response (:class:`Orbit`)
``predict_amplitude(...)``  ``max_t |x_s(t)|`` of every signal on responses, (n, n_signals)
``summary()``               JSON-able: ``parameters`` and ``standard_errors`` by name, losses
``save(dir)`` / ``load``    a model directory (:mod:`bifid.identify._persistence`)
==========================  =================================================================

Queries use the names of ``bifid predict``: the continuation parameter's ``range``, and
``forcing`` (an FRC at that forcing, ``range`` in Ω) or ``omega`` (an S-curve at that
frequency, ``range`` in F); a forced model without either predicts its backbone
(``range`` in amplitude). A model refuses a question it cannot answer with a
:class:`~bifid.errors.BifidInputError` that says which ones it can.

``level`` asks for intervals at a confidence level. A method without calibrated intervals
refuses it rather than drawing a band whose level would be a guess.
"""

from __future__ import annotations

import abc
import inspect
import math
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar, Literal

import numpy as np

from bifid.continuation import Diagram
from bifid.errors import BifidInputError, NotFittedError
from bifid.identify._intervals import check_level
from bifid.identify._persistence import load_estimator, save_estimator

__all__ = ["DiagramQuery", "Estimator", "IdentifiedModel", "Orbit"]

DiagramKind = Literal["bifurcation", "frc", "scurve", "backbone"]


@dataclass(frozen=True)
class Orbit:
    """One period of a periodic response predicted by a model.

    Attributes
    ----------
    param : str
        Name of the parameter ``value`` refers to (``Omega`` for a point of an FRC).
    value : float
        Its value.
    stable : bool
        Stability of the response.
    period : float
        Period [s].
    t : ndarray of shape (n_points,)
        Times over one period, ``[0, period)``.
    signals : ndarray of shape (n_points, n_signals)
        Every signal of the model at ``t``.
    signal_names : tuple of str
    forcing, omega : float, optional
        The forcing amplitude and frequency of a forced response.
    """

    param: str
    value: float
    stable: bool
    period: float
    t: np.ndarray
    signals: np.ndarray
    signal_names: tuple[str, ...]
    forcing: float | None = None
    omega: float | None = None

    @property
    def amplitude(self) -> np.ndarray:
        """``max_t |x_s(t)|`` of each signal over the sampled period."""
        return np.max(np.abs(self.signals), axis=0)

    def signal(self, name: str) -> np.ndarray:
        """The samples of one signal."""
        if name not in self.signal_names:
            raise BifidInputError(
                f"unknown signal {name!r}; the orbit has {', '.join(self.signal_names)}."
            )
        return self.signals[:, self.signal_names.index(name)]


@dataclass(frozen=True)
class DiagramQuery:
    """A validated ``predict_diagram`` question (see the module docstring).

    ``range`` is ``None`` (the model's default window) or ``(low, high)`` with
    ``low < high``, in the units of the diagram's continuation parameter.
    """

    kind: DiagramKind
    param: str | None
    range: tuple[float, float] | None
    forcing: float | None
    omega: float | None
    n_points: int


def _positive(name: str, value: float | None) -> float | None:
    if value is None:
        return None
    v = float(value)
    if not (math.isfinite(v) and v > 0):
        raise BifidInputError(f"{name} must be a positive finite number, got {value!r}.")
    return v


def _range(value: Sequence[float] | None) -> tuple[float, float] | None:
    if value is None:
        return None
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        raise BifidInputError(f"range must be two numbers (low, high), got {value!r}.") from None
    if not (math.isfinite(lo) and math.isfinite(hi)) or lo == hi:
        raise BifidInputError(f"range must be two different finite numbers, got {value!r}.")
    return (lo, hi) if lo < hi else (hi, lo)


def _tuples(values: list) -> list:
    """Nested lists as nested tuples (e.g. monomial exponents)."""
    return [tuple(_tuples(v)) if isinstance(v, list) else v for v in values]


class Estimator(abc.ABC):
    """Abstract base of bifid's fitted estimators: hyperparameters, fitted check, summary
    and persistence (one model format, :mod:`bifid.identify._persistence`).

    Subclasses set :attr:`model_type` and :attr:`_fitted_attribute`, and implement
    ``fit``, :meth:`summary`, :meth:`_state` and :meth:`_restore`.
    """

    #: name of the model type in ``model.json`` (``bifid predict`` dispatches on it)
    model_type: ClassVar[str]
    #: fitted attribute whose presence means the model is fitted
    _fitted_attribute: ClassVar[str]

    # ------------------------------------------------------------------ hyperparameters
    def get_params(self) -> dict[str, Any]:
        """Hyperparameters by name: the arguments of ``__init__`` (scikit-learn convention)."""
        names = [
            p.name
            for p in inspect.signature(type(self).__init__).parameters.values()
            if p.name != "self" and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)
        ]
        return {n: getattr(self, n) for n in names}

    @classmethod
    def _decode_hyperparameters(cls, hyper: dict[str, Any]) -> dict[str, Any]:
        """Hyperparameters read back from JSON, as ``__init__`` takes them (JSON turns
        tuples into lists: sequences are given back as tuples)."""
        return {k: tuple(_tuples(v)) if isinstance(v, list) else v for k, v in hyper.items()}

    def _check_fitted(self) -> None:
        if not hasattr(self, self._fitted_attribute):
            raise NotFittedError(
                f"This {type(self).__name__} is not fitted yet; call fit(...) or load a "
                "saved model first."
            )

    # -------------------------------------------------------------------- summary / io
    @abc.abstractmethod
    def summary(self) -> dict[str, Any]:
        """JSON-able account of the fit: ``parameters`` and ``standard_errors`` (by name),
        ``losses`` and what else the method reports."""

    @abc.abstractmethod
    def _state(self) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
        """Fitted state as JSON-able values and numeric arrays (for :meth:`save`)."""

    @abc.abstractmethod
    def _restore(self, state: dict[str, Any], arrays: dict[str, np.ndarray]) -> None:
        """Set the fitted attributes from :meth:`_state`'s output (for :meth:`load`)."""

    def save(self, directory: str | Path, *, settings: dict[str, Any] | None = None) -> Path:
        """Save as ``directory/model.json`` + ``arrays.npz`` (no pickle).

        ``settings`` (provenance: data files, command line) is stored alongside.
        """
        self._check_fitted()
        return save_estimator(self, directory, settings)

    @classmethod
    def load(cls, directory: str | Path) -> Estimator:
        """Load a model saved by :meth:`save`.

        Raises
        ------
        BifidInputError
            If the directory holds another model type or is malformed.
        """
        return load_estimator(directory, cls)


class IdentifiedModel(Estimator):
    """Abstract base of bifid's identified models (the contract of the module docstring).

    Subclasses set :attr:`model_type`, :attr:`kinds` (the diagrams they predict; the first
    is the default) and implement the abstract methods.
    """

    #: diagram kinds the model predicts, the default first
    kinds: ClassVar[tuple[str, ...]]
    #: what the model offers instead of calibrated intervals (said when ``level`` is asked)
    uncertainty_note: ClassVar[str] = "no uncertainty estimate"
    #: whether ``predict_diagram(level=...)`` gives calibrated intervals
    calibrated: ClassVar[bool] = False

    # ---------------------------------------------------------------------------- fit
    @abc.abstractmethod
    def fit(self, dataset: Any, **extra: Any) -> IdentifiedModel:
        """Fit the model to a dataset (path, ``xarray.Dataset`` or list of them)."""

    # ----------------------------------------------------------------------- predict
    def predict_diagram(
        self,
        *,
        kind: DiagramKind | None = None,
        param: str | None = None,
        range: Sequence[float] | None = None,
        forcing: float | None = None,
        omega: float | None = None,
        level: float | None = None,
        n_points: int = 100,
    ) -> Diagram:
        """The model's answer to a continuation question, as a :class:`Diagram`.

        Parameters
        ----------
        kind : {"bifurcation", "frc", "scurve", "backbone"}, optional
            Default: ``frc`` when ``forcing`` is given, ``scurve`` when ``omega`` is
            given, else the model's first kind.
        param : str, optional
            Name of the continuation parameter (checked against the model's).
        range : (float, float), optional
            Interval of the continuation parameter (bifurcation: the parameter; FRC: Ω;
            S-curve: F; backbone: amplitude). Default: the trained range, widened.
        forcing : float, optional
            Forcing amplitude of an FRC.
        omega : float, optional
            Forcing frequency of an S-curve [rad/s].
        level : float in (0, 1), optional
            Confidence level of intervals on special points and branches.
        n_points : int
            Points along each branch (where the method samples it).

        Raises
        ------
        BifidInputError
            For a question the model cannot answer, invalid values, or a ``level`` the
            model has no calibrated intervals for.
        NotFittedError
            Before ``fit``.
        """
        self._check_fitted()
        query = self._query(kind, param, range, forcing, omega, n_points)
        lv = None if level is None else check_level(level)
        if lv is not None and not self.calibrated:
            raise BifidInputError(
                f"{type(self).__name__} has no calibrated intervals yet, so level={lv:g} "
                f"cannot be honoured; predict without a level ({self.uncertainty_note})."
            )
        diagram = self._predict_diagram(query)
        if lv is not None:
            self._add_intervals(diagram, query, lv)
        return diagram

    def _add_intervals(self, diagram: Diagram, query: DiagramQuery, level: float) -> None:
        """Fill the intervals of a predicted diagram at ``level`` and set ``diagram.level``
        (models with :attr:`calibrated` intervals override this)."""
        raise NotImplementedError

    def _query(self, kind, param, range_, forcing, omega, n_points) -> DiagramQuery:
        forcing = _positive("forcing", forcing)
        omega = _positive("omega", omega)
        if kind is None:
            kind = (
                "frc" if forcing is not None else "scurve" if omega is not None else self.kinds[0]
            )
        if kind not in ("bifurcation", "frc", "scurve", "backbone"):
            raise BifidInputError(
                f"kind must be bifurcation, frc, scurve or backbone, got {kind!r}."
            )
        if kind not in self.kinds:
            raise BifidInputError(
                f"a {self.model_type} model predicts {' / '.join(self.kinds)} diagrams, not "
                f"{kind!r}" + (" (it has no forcing)" if kind in ("frc", "scurve") else "") + "."
            )
        if kind == "frc" and forcing is None:
            raise BifidInputError("an FRC needs the forcing amplitude (forcing=F).")
        if kind == "scurve" and omega is None:
            raise BifidInputError("an S-curve needs the forcing frequency (omega=W).")
        extra = [
            n
            for n, v, k in (("forcing", forcing, "frc"), ("omega", omega, "scurve"))
            if v is not None and kind != k
        ]
        if extra:
            raise BifidInputError(f"{' and '.join(extra)} does not apply to a {kind} diagram.")
        if not (isinstance(n_points, (int, np.integer)) and n_points >= 2):
            raise BifidInputError(f"n_points must be an integer >= 2, got {n_points!r}.")
        return DiagramQuery(
            kind=kind,
            param=param,
            range=_range(range_),
            forcing=forcing,
            omega=omega,
            n_points=int(n_points),
        )

    @abc.abstractmethod
    def _predict_diagram(self, query: DiagramQuery) -> Diagram:
        """Answer a validated query (fitted model)."""

    def predict_orbit(
        self,
        value: float,
        *,
        stable: bool = True,
        forcing: float | None = None,
        omega: float | None = None,
        n_points: int = 256,
    ) -> Orbit:
        """One period of every signal on the response at ``value`` of the parameter.

        ``value`` is the bifurcation parameter (autonomous models), Ω when ``forcing`` is
        given, F when ``omega`` is given. ``stable`` picks the response where several
        coexist (of several with that stability, the largest).

        Raises
        ------
        BifidInputError
            If the model has no response of that stability there, or the question does
            not fit the model (forcing for an autonomous model, none for a forced one).
        """
        self._check_fitted()
        self._check_response(forcing, omega)
        if not (isinstance(n_points, (int, np.integer)) and n_points >= 2):
            raise BifidInputError(f"n_points must be an integer >= 2, got {n_points!r}.")
        (v,) = self._values(value)
        return self._predict_orbit(v, bool(stable), forcing, omega, int(n_points))

    def predict_amplitude(
        self,
        values: Sequence[float] | float,
        *,
        stable: bool = True,
        forcing: float | None = None,
        omega: float | None = None,
    ) -> np.ndarray:
        """``max_t |x_s(t)|`` of every signal on the responses at ``values``.

        Same conventions as :meth:`predict_orbit`; returns shape
        ``(len(values), n_signals)``.

        Raises
        ------
        BifidInputError
            Where the model has no response of that stability.
        """
        self._check_fitted()
        self._check_response(forcing, omega)
        return self._predict_amplitude(self._values(values), bool(stable), forcing, omega)

    def _check_response(self, forcing: float | None, omega: float | None) -> None:
        if "frc" not in self.kinds:
            if forcing is not None or omega is not None:
                raise BifidInputError(
                    f"a {self.model_type} model is autonomous: it has no forcing; give the "
                    "bifurcation parameter's value only."
                )
        elif (forcing is None) == (omega is None):
            raise BifidInputError(
                "a forced response needs exactly one of forcing=F (the value is then Ω) or "
                "omega=W (the value is then F)."
            )

    @staticmethod
    def _values(values: Sequence[float] | float) -> np.ndarray:
        v = np.atleast_1d(np.asarray(values, dtype=float))
        if v.ndim != 1 or v.size == 0 or not np.all(np.isfinite(v)):
            raise BifidInputError(f"values must be finite numbers, got {values!r}.")
        return v

    @abc.abstractmethod
    def _predict_orbit(
        self, value: float, stable: bool, forcing: float | None, omega: float | None, n: int
    ) -> Orbit:
        """:meth:`predict_orbit` on checked arguments (fitted model)."""

    @abc.abstractmethod
    def _predict_amplitude(
        self, values: np.ndarray, stable: bool, forcing: float | None, omega: float | None
    ) -> np.ndarray:
        """:meth:`predict_amplitude` on checked arguments (fitted model)."""

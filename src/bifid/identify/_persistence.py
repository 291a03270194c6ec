"""Saving and loading identified models: one format for every method.

A model is a directory written by :func:`bifid.io.save_model`: ``model.json`` holds the
model type, the hyperparameters (the arguments of ``__init__``), the fitted state that is
JSON-able, the model's :meth:`summary` (so a reader needs no bifid to see the fitted
parameters) and the provenance ``settings``; ``arrays.npz`` holds the numeric arrays,
checksummed, never pickled.

Loading reads the type, builds the estimator class registered for it with the stored
hyperparameters and hands it the state (:meth:`_restore`). Every malformed file ends in a
:class:`~bifid.errors.BifidInputError` naming the directory.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from bifid.errors import BifidInputError
from bifid.io import load_model, save_model

__all__ = ["load", "load_estimator", "model_types", "register_model_type", "save_estimator"]

_TYPES: dict[str, type] = {}


def register_model_type(cls: type) -> type:
    """Class decorator: make ``cls`` loadable by its ``model_type``."""
    _TYPES[cls.model_type] = cls
    return cls


def model_types() -> tuple[str, ...]:
    """The registered model types."""
    return tuple(sorted(_TYPES))


def save_estimator(model: Any, directory: str | Path, settings: dict[str, Any] | None) -> Path:
    """Write a fitted estimator (see the module docstring); returns the directory."""
    state, arrays = model._state()
    params = {"hyperparameters": model.get_params(), "state": state, "summary": model.summary()}
    return save_model(directory, model.model_type, params, arrays, settings or {})


def load_estimator(directory: str | Path, cls: type | None = None) -> Any:
    """Load a model directory; with ``cls``, insist that it holds that class's type.

    Raises
    ------
    BifidInputError
        Unknown or unexpected model type, or a malformed model.
    """
    meta, arrays = load_model(directory)
    kind = meta.get("type")
    if cls is not None and kind != cls.model_type:
        raise BifidInputError(f"{str(directory)!r} holds a {kind!r} model, not {cls.model_type!r}.")
    target = _TYPES.get(kind) if cls is None else cls
    if target is None:
        raise BifidInputError(
            f"{str(directory)!r} holds a model of unknown type {kind!r}; bifid reads "
            f"{', '.join(model_types())}."
        )
    try:
        params = meta["params"]
        model = target(**target._decode_hyperparameters(dict(params["hyperparameters"])))
        model._restore(dict(params["state"]), dict(arrays))
    except (KeyError, TypeError, ValueError, IndexError) as exc:
        raise BifidInputError(
            f"{str(directory)!r} is not a valid {kind} model ({type(exc).__name__}: {exc})."
        ) from None
    model.settings_ = dict(meta.get("settings") or {})
    return model


def load(directory: str | Path) -> Any:
    """Load any bifid model directory (the class is chosen by the stored type).

    Raises
    ------
    BifidInputError
        If the directory is not a bifid model of a known type.
    """
    return load_estimator(directory)

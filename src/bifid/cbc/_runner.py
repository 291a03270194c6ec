"""The one CBC campaign runner (:func:`run_campaign`): every campaign, new or resumed.

The CLI (``bifid cbc``), the campaign functions (:func:`bifid.cbc.lco_campaign`,
:func:`bifid.cbc.scurve_campaign`, :func:`bifid.cbc.frc_campaign`) and the demos all run
their campaigns through it; what a campaign does is described in
:mod:`bifid.cbc._campaign`.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping
from pathlib import Path
from typing import Any

from threadpoolctl import threadpool_limits

from bifid.cbc._campaign import Campaign, CampaignResult, CampaignSpec
from bifid.cbc._campaign_result import result_of
from bifid.cbc._campaign_tasks import run_tasks
from bifid.cbc._checkpoint import CampaignFile, settings_difference
from bifid.cbc._rig import AbstractRig
from bifid.errors import BifidInputError

__all__ = ["run_campaign"]


def run_campaign(
    spec: CampaignSpec,
    rig: AbstractRig,
    *,
    out: str | Path | None = None,
    resume: bool = False,
    dataset_kwargs: Mapping[str, Any] | None = None,
    settings: Mapping[str, Any] | None = None,
    on_point: Callable[[Any], None] | None = None,
    on_evaluation: Callable[[int], None] | None = None,
) -> CampaignResult:
    """Run (or resume) a campaign on ``rig`` (module docstring).

    Parameters
    ----------
    spec : CampaignSpec
    rig : AbstractRig
        Set up for ``spec`` (its parameters, outputs, noise).
    out : path, optional
        The dataset file; written at every recorded point.
    resume : bool
        Continue the campaign in ``out`` (which must exist and hold the same campaign).
    dataset_kwargs : dict
        Arguments of the dataset builder (signal names, units, source, ...).
    settings : dict, optional
        Provenance stored with the dataset and the diagram.
    on_point, on_evaluation : callable, optional
        Progress: each recorded point; each rig evaluation (called with 1).

    Returns
    -------
    CampaignResult

    Raises
    ------
    BifidInputError
        ``out`` exists without ``resume``, or is missing, another campaign or malformed
        with it.
    """
    kind = "lco" if spec.protocol == "ppcbc" else "forced"
    kw = {
        **dict(dataset_kwargs or {}),
        "settings": {**dict(settings or {}), "campaign": spec.identity()},
    }
    file = None if out is None else CampaignFile(out, kind, kw)
    camp = Campaign(spec, rig, file, kw, on_point, on_evaluation)
    resumed = 0
    if file is not None:
        if resume and not file.path.exists():
            raise BifidInputError(f"--resume: {file.path} does not exist (nothing to resume).")
        if not resume and file.path.exists():
            raise BifidInputError(
                f"{file.path} exists; pass --resume to continue it or choose another --out."
            )
        file.clean()
        if resume:
            records, state, _ = file.read()
            if state.get("digest") != camp.digest:
                diff = settings_difference(state.get("identity", {}), spec.identity())
                raise BifidInputError(
                    f"--resume: {file.path} holds another campaign ({diff or 'other settings'})."
                )
            camp.restore(records, state)
            resumed = len(camp.records)
    # small dense algebra everywhere: multi-threaded BLAS on a loaded machine is many times
    # slower than one thread
    with threadpool_limits(1, user_api="blas"):
        if not camp.cursor["done"]:
            run_tasks(camp)
            camp.cursor["done"] = True
            camp.cursor["branch"] = None
            camp.checkpoint()
    return result_of(camp, resumed)

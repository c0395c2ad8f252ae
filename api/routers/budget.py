"""``GET /budget`` (issue 32): the measurement's error budget of the daemon's set-up, in the shape
of thesis Table 4.5 (daemon/analysis/budget.py).

The daemon does not record for it: its camera, IR and robot belong to its runs. So the answer
is the latest budget ``thermocomp budget --save`` kept in the data directory (with its
recordings: the camera's drift, the vibration, the centroid), or, when there is none or when
asked (``fresh``, or another ``target_um``), one made now from the settings alone: the
analytic and model rows, the measured ones saying how to get them.
"""

from __future__ import annotations

from typing import Annotated, Any, Literal

from fastapi import APIRouter, Query
from pydantic import BaseModel, Field

from api.deps import DaemonDep, ReadAccess, SettingsDep
from api.errors import ApiError, ErrorBody
from config import Settings
from daemon.commands.budget_run import BudgetError, live_budget
from daemon.storage.budgets import read_saved_budget

router = APIRouter(tags=["budget"], dependencies=[ReadAccess])


class BudgetSource(BaseModel):
    key: str
    name: str
    section: str = Field(description="The thesis's section, e.g. 4.3.")
    evidence: str = Field(description="analytic, measured, model, not quantified, not applicable")
    delta_l_um: float | None = Field(
        description="Its error along the measured deformation (um): a scatter at twice its "
        "1-sigma, an analytic source at its worst case, a drift its whole change."
    )
    effect: str
    remedy: str = Field(description="What would reduce it (Table 4.5's last column).")
    basis: str = Field(description="How the number was obtained, with its inputs.")
    conditional: str | None = Field(
        description="Set: it happens only then (a bound, left out of the resolution)."
    )
    detail: dict[str, float | str | None]


class BudgetPose(BaseModel):
    pose: str
    expected_um: float
    measurement_um: float | None
    model_um: float | None
    cameras_seeing: int | None


class BudgetAnswer(BaseModel):
    source: Literal["saved", "live"] = Field(
        description="saved: the latest `thermocomp budget --save`; live: made now, unrecorded."
    )
    made_at: str | None = Field(description="When a saved budget was made (ISO 8601).")
    recorded: bool = Field(description="Whether its measured rows come from recordings.")
    setup: str
    expected_um: float = Field(description="The deformation the measurement must see (um).")
    expected_basis: str
    target_um: float
    resolution_um: float = Field(description="Root sum of squares of the unconditional rows.")
    resolves: bool
    verdict: str
    coverage: float
    sources: list[BudgetSource] = Field(description="Ranked: the largest error first.")
    poses: list[BudgetPose]
    warnings: list[str]
    notes: list[str]


def _live(settings: Settings, target_um: float | None) -> dict[str, Any]:

    return live_budget(settings, target_um).to_dict()


@router.get(
    "/budget",
    responses={422: {"model": ErrorBody, "description": "the set-up gives no budget"}},
)
async def get_budget(
    settings: SettingsDep,
    daemon: DaemonDep,
    target_um: Annotated[
        float | None,
        Query(gt=0, le=10000, description="Judge against this target (um), made now."),
    ] = None,
    fresh: Annotated[bool, Query(description="Make it now even when one is saved.")] = False,
) -> BudgetAnswer:
    """The set-up's error budget: each source's error against the expected deformation,
    ranked, with what would reduce it, and whether the set-up resolves its target."""

    if target_um is None and not fresh:
        saved = await daemon.read(read_saved_budget, settings.storage.data_dir)
        if saved is not None:
            try:
                return BudgetAnswer.model_validate({**saved, "source": "saved"})
            except ValueError:
                pass  # a file of another version: make one now
    try:
        made = await daemon.read(_live, settings, target_um)
    except (BudgetError, ValueError, LookupError) as err:
        raise ApiError(422, "validation", f"no budget for this set-up: {err}") from err
    return BudgetAnswer.model_validate(
        {**made, "source": "live", "made_at": None, "recorded": False}
    )

"""``GET /kinds``: how the dashboard shows each run kind (issue 27: a kind owns its view, so the
page names no kind), and which kind a start from the configured parameters makes."""

from __future__ import annotations

from fastapi import APIRouter
from pydantic import BaseModel, Field

from api.deps import DaemonDep, ReadAccess, SettingsDep
from daemon.run.kind import KindView
from daemon.run.kinds import chosen_kind, kind_views
from daemon.run.states import RunParameters

router = APIRouter(tags=["runs"], dependencies=[ReadAccess])


class KindList(BaseModel):
    kinds: list[KindView] = Field(description="Every run kind this daemon knows, by name.")
    default: str = Field(
        description="The kind a run started with the configured parameters is (what the start "
        "form asks for): chosen by the robot and the parameters, daemon/run/kinds.py."
    )


@router.get("/kinds")
async def list_kinds(settings: SettingsDep, daemon: DaemonDep) -> KindList:
    """Each run kind's view: its plots and their titles and axes, its start form's fields and
    title, how the runs table describes its runs, whether reference runs apply and which runs
    qualify, whether rotation is measured. Each run record's ``kind`` names one of them (null
    for a run recorded before runs said their kind)."""
    default = chosen_kind(daemon.devices.robot, RunParameters.from_settings(settings))
    return KindList(kinds=list(kind_views()), default=default.name)

"""``GET /devices/preview``: the bring-up preview while the daemon is idle (issue 18).

One frame (spot ringed), one thermal image (every IR region drawn and labelled) and the robot's
pose, from the daemon's own open devices (daemon/run/devices_check.py), as a PNG. Refused with 409
while a run is active: a preview grab would take a frame, an IR reading and a console round trip
from the run's steps.
"""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import Response

from api.deps import DaemonDep, ReadAccess
from api.errors import ApiError, ErrorBody
from daemon.run.devices_check import preview_png
from daemon.service import RunConflictError
from drivers.errors import DeviceError

router = APIRouter(tags=["devices"], dependencies=[ReadAccess])


@router.get(
    "/devices/preview",
    response_class=Response,
    responses={
        200: {"content": {"image/png": {}}, "description": "the preview image"},
        409: {"model": ErrorBody, "description": "a run is active"},
        503: {"model": ErrorBody, "description": "no device gave an image"},
    },
)
async def devices_preview(daemon: DaemonDep) -> Response:
    """The camera frame with the spot marked beside the thermal image with the IR regions;
    the devices' findings in ``X-Thermocomp-*`` headers (spot position, failures)."""
    try:
        check = await daemon.check_devices()
    except RunConflictError as err:
        raise ApiError(409, "conflict", f"{err}: the preview is available while idle") from err
    try:
        png = await daemon.read(preview_png, check)
    except DeviceError as err:
        raise ApiError(503, "device", "; ".join(check.errors.values()) or str(err)) from err
    headers = {}
    if check.centroid is not None:
        headers["X-Thermocomp-Spot-Px"] = (
            f"{check.centroid['x_px']:.3f},{check.centroid['y_px']:.3f}"
        )
    if check.tool_frames:
        headers["X-Thermocomp-Cameras"] = ", ".join(name for name, _ in check.tool_frames)
    if check.errors:
        headers["X-Thermocomp-Device-Errors"] = "; ".join(
            f"{device}: {error}" for device, error in check.errors.items()
        )[:1000]
    return Response(content=png, media_type="image/png", headers=headers)

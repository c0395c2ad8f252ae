"""Hostile requests (issue 26): bodies and paths sent to a real ``thermocomp serve`` whose
data directory holds bad files. Each must be answered with a 4xx (never a 5xx) whose JSON
``message`` is one line naming the problem; the listings answer 200 and list a bad file as
unreadable; the server keeps serving (its /health answers after every case)."""

from __future__ import annotations

import json
from dataclasses import dataclass, field

from tests.hostile.corpus import DUTY, MODEL


@dataclass(frozen=True)
class ApiCase:
    id: str
    method: str
    path: str
    status: tuple[int, ...]
    says: str = ""  # a regular expression the message matches (case-insensitive)
    body: object = None  # JSON-encoded unless bytes
    headers: dict[str, str] = field(default_factory=dict)


def run(id: str, body: object, status: tuple[int, ...], says: str = "") -> ApiCase:
    return ApiCase(f"api/runs/{id}", "POST", "/api/v1/runs", status, says, body)


def nested(depth: int) -> bytes:
    return ('{"a":' * depth + "1" + "}" * depth).encode()


API_CASES = [
    run("reference-2-63", {"reference_run": 2**63}, (422,), r"reference_run"),
    run("reference-2-64", {"reference_run": 2**64}, (422,), r"reference_run"),
    run("reference-negative", {"reference_run": -1}, (422,), r"reference_run"),
    run("reference-missing", {"reference_run": 2**63 - 1}, (422,), r"no such run"),
    run("network-typo", {"network": "thesis-two-lnk"}, (404,), r"did you mean 'thesis-two-link'"),
    run("network-path", {"network": "../../etc/passwd"}, (422,), r"network"),
    run("network-saved-bad", {"network": "broken"}, (422,), r"broken\.toml"),
    run("duty-typo", {"duty_cycle": "pick-and-plce"}, (422,), r"'a465-pick-and-place'"),
    run(
        "arm-model-typo",
        {"duty_cycle": "a465-pick-and-place", "arm_model": "cla"},
        (404,),
        r"did you mean 'cal'",
    ),
    run(
        "arm-model-path",
        {"duty_cycle": "a465-pick-and-place", "arm_model": "../cal"},
        (422,),
        r"arm_model",
    ),
    run(
        "arm-model-bad",
        {"duty_cycle": "a465-pick-and-place", "arm_model": "broken"},
        (422,),
        r"broken\.toml",
    ),
    run("duty-path", {"duty_cycle": "{t}/fifo.toml"}, (422,), r"duty_cycle"),
    run("duration-1e308", {"duration_s": 1e308}, (422,), r"duration_s"),
    run("heat-many", {"heat_w": {f"n{i}": 1.0 for i in range(2_000)}}, (422,), r"heat_w"),
    run("unknown-field", {"duration": 5}, (422,), r"duration"),
    run("string-for-number", {"step_s": "fast"}, (422,), r"step_s"),
    run("bool-as-string", {"duration_s": True}, (422,), r"duration_s"),
    ApiCase("api/runs/nested-json", "POST", "/api/v1/runs", (400, 413, 422), "", nested(10_000)),
    ApiCase(
        "api/runs/not-json",
        "POST",
        "/api/v1/runs",
        (400, 422),
        "",
        b"{not json",
        {"Content-Type": "application/json"},
    ),
    ApiCase(
        "api/runs/nan-literal",
        "POST",
        "/api/v1/runs",
        (400, 422),
        "",
        b'{"duration_s": NaN}',
        {"Content-Type": "application/json"},
    ),
    ApiCase(
        "api/runs/huge-body",
        "POST",
        "/api/v1/runs",
        (413,),
        "",
        json.dumps({"network": "x" * (2 * 1024 * 1024)}).encode(),
        {"Content-Type": "application/json"},
    ),
    ApiCase("api/run/id-2-64", "GET", "/api/v1/runs/18446744073709551616", (404, 422)),
    ApiCase("api/run/id-2-63", "GET", "/api/v1/runs/9223372036854775808", (404, 422)),
    ApiCase("api/run/id-text", "GET", "/api/v1/runs/abc", (422,)),
    ApiCase(
        "api/run/steps-huge", "GET", "/api/v1/runs/1/steps?from=99999999999999999999", (404, 422)
    ),
    ApiCase("api/run/frame-huge", "GET", "/api/v1/runs/1/frames/99999999999999999999", (404, 422)),
    ApiCase(
        "api/arm-models/bad-by-name", "GET", "/api/v1/arm-models/broken", (404, 422), r"broken"
    ),
    ApiCase("api/arm-models/typo", "GET", "/api/v1/arm-models/cla", (404,), r"cla"),
    ApiCase("api/networks/listing", "GET", "/api/v1/networks", (200,)),
    ApiCase("api/arm-models/listing", "GET", "/api/v1/arm-models", (200,)),
]

#: The bad files of the server's data directory (``{t}``: the test's folder).
DATA_FILES: dict[str, bytes | str] = {
    "data/networks/broken.toml": "x = " + "[" * 3000 + "]" * 3000,
    "data/networks/binary.toml": bytes(range(256)),
    "data/networks/huge.toml": "[[segments]]\nlength_mm = 500.0\nwidth_mm = 30.0\n"
    'thickness_mm = 10.0\nmaterial = "6061-T6"\nnode_spacing_mm = 0.0001\nh_w_per_m2k = 10.0\n',
    "data/arm-models/cal.toml": MODEL,
    "data/arm-models/broken.toml": b'format = 1\nname = "\xff"\n',
    "data/arm-models/deep.toml": "x = " + "{a=" * 2000 + "1" + "}" * 2000,
    "ur5e-duty.toml": DUTY.replace('arm = "crs-a465"', 'arm = "ur5e"'),
    "notes.toml": "this is not TOML [",
}
#: Files made named pipes: reading one would block the server's worker forever.
FIFOS = ("fifo.toml", "data/networks/pipe.toml", "data/arm-models/pipe.toml")

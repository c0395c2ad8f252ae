"""Hostile requests through a real ``thermocomp serve`` (issue 26): a data directory holding
bad files (networks, arm models, pipes) and requests written to break the API. Every answer
is a 4xx with one line naming the problem, never a 5xx; the listings skip a bad file (listed
as unreadable) instead of failing; the server answers /health after each."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Iterator
from pathlib import Path

import httpx
import pytest

from tests.helpers import running_server
from tests.hostile.api_cases import API_CASES, DATA_FILES, FIFOS, ApiCase
from tests.hostile.corpus import ARM_SIM, Case
from tests.test_api_server import CONTROL

AUTH = {"Authorization": f"Bearer {CONTROL}"}


@pytest.fixture(scope="module")
def server(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[str, Path]]:
    folder = tmp_path_factory.mktemp("hostile-api")
    Case("server", "api", (), "", DATA_FILES).write(folder)
    for name in FIFOS:
        os.mkfifo(folder / name)
    config = folder / "serve.toml"
    config.write_text(ARM_SIM.replace("{t}", str(folder)))
    env = {
        "THERMOCOMP_API__CONTROL_TOKEN": CONTROL,
        "THERMOCOMP_API__READ_TOKEN": "r" * 24,
        # the cases come faster than a person clicks: the control rate limit is not tested here
        "THERMOCOMP_API__CONTROL_RATE_PER_S": "1000",
        "THERMOCOMP_API__CONTROL_BURST": "1000",
        # the data directory holding the hostile files (the server's own temporary one else)
        "THERMOCOMP_STORAGE__DATA_DIR": str(folder / "data"),
    }
    with running_server(["--config", str(config)], env=env, timeout_s=90) as base_url:
        yield base_url, folder


@pytest.mark.parametrize("case", API_CASES, ids=[case.id for case in API_CASES])
def test_a_hostile_request_gets_one_line(case: ApiCase, server: tuple[str, Path]) -> None:
    base_url, folder = server
    body = case.body
    if isinstance(body, dict):
        body = json.loads(json.dumps(body).replace("{t}", str(folder)))
    content = body if isinstance(body, bytes) else None
    with httpx.Client(base_url=base_url, timeout=60, headers=AUTH) as client:
        answer = client.request(
            case.method,
            case.path,
            content=content,
            json=None if content is not None or body is None else body,
            headers=case.headers,
        )
        assert answer.status_code in case.status, (answer.status_code, answer.text[:500])
        if answer.status_code >= 400:
            message = answer.json()["message"]
            assert "\n" not in message and "Traceback" not in message, message
            assert re.search(case.says, message, re.IGNORECASE), message
        assert client.get("/api/v1/health").status_code == 200


def test_the_listings_name_each_bad_file_once(server: tuple[str, Path]) -> None:
    base_url, _ = server
    with httpx.Client(base_url=base_url, timeout=120, headers=AUTH) as client:
        networks = client.get("/api/v1/networks").json()
        arm_models = client.get("/api/v1/arm-models").json()
    bad_networks = {item["name"]: item["error"] for item in networks["unreadable"]}
    assert set(bad_networks) == {"broken", "binary", "huge", "pipe"}, bad_networks
    assert "nested over 16" in bad_networks["broken"]
    assert "binary file" in bad_networks["binary"]
    assert "over 10000 nodes" in bad_networks["huge"]
    assert "not a regular file" in bad_networks["pipe"]
    assert [model["name"] for model in arm_models["arm_models"]] == ["cal"]
    bad_models = {item["name"]: item["error"] for item in arm_models["unreadable"]}
    assert set(bad_models) == {"broken", "deep", "pipe"}, bad_models
    assert all("\n" not in error for error in [*bad_networks.values(), *bad_models.values()])

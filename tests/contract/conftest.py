"""The robot under the contract: one parametrised fixture over tests/contract/adapters.py."""

from __future__ import annotations

from collections.abc import AsyncIterator

import pytest

from tests.contract.adapters import ADAPTERS, Subject


@pytest.fixture(params=sorted(ADAPTERS))
async def subject(request: pytest.FixtureRequest) -> AsyncIterator[Subject]:
    async with ADAPTERS[request.param]() as opened:
        await opened.robot.teach_goal()
        yield opened

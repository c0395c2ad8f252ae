"""Suite-wide fixtures: every test must leave no asyncio task running behind it."""

import asyncio
from collections.abc import AsyncIterator

import pytest


@pytest.fixture(autouse=True)
async def fail_on_leaked_tasks() -> AsyncIterator[None]:
    """Fail a test that leaves tasks running (as ophyd-async does): a leaked task is a
    device loop or a reader that nobody will ever stop."""
    before = asyncio.all_tasks()
    yield
    for _ in range(3):  # let tasks that are just finishing finish
        await asyncio.sleep(0)
    current = asyncio.current_task()
    leaked = [t for t in asyncio.all_tasks() - before if t is not current and not t.done()]
    for task in leaked:
        task.cancel()
    if leaked:
        await asyncio.gather(*leaked, return_exceptions=True)
        pytest.fail(f"test left {len(leaked)} asyncio task(s) running: {leaked!r}")

"""Fixtures shared by every test directory: a headless chromium and its pages."""

from __future__ import annotations

from collections.abc import Iterator

import pytest


@pytest.fixture(scope="module")
def browser() -> Iterator[object]:
    """Module-scoped: Playwright's sync API holds an event loop on the main thread while it
    is open, so it is closed before another module's tests (asyncio.run) run. Skips with the
    reason when this machine has no chromium."""
    from station.ui.headless import chromium, chromium_missing_reason
    from tests.tools import missing

    reason = chromium_missing_reason()
    if reason:
        missing(f"browser tests: {reason}")
    with chromium() as b:
        yield b


@pytest.fixture
def page(browser: object) -> Iterator[object]:
    context = browser.new_context(viewport={"width": 1280, "height": 900})  # type: ignore[attr-defined]
    pg = context.new_page()
    pg.set_default_timeout(10_000)
    try:
        yield pg
    finally:
        context.close()


@pytest.fixture
def mbpoll() -> str:
    """The third-party Modbus client (Debian's mbpoll): skipped without it, failed in CI."""
    from tests.tools import need

    return need("mbpoll")


@pytest.fixture
def socat() -> str:
    """socat, a serial terminal and TCP bridge: skipped without it, failed in CI."""
    from tests.tools import need

    return need("socat")

"""A real headless browser for the page tests: Debian's Chromium driven by playwright.

Playwright's own browser download does not work on this machine, so the system Chromium
(`/usr/bin/chromium`, installed by scripts/setup.sh) is launched by path. Fixtures:
  * `browser`: one Chromium for the session;
  * `page`: a fresh context and page; every console error and uncaught page error is collected
    in `page.errors` (a list of strings), which a test asserts empty once the page has loaded;
  * `offline_page`: the same with the network switched off (a self-contained file must work).
"""

from __future__ import annotations

import os
from collections.abc import Iterator

import pytest
from playwright.sync_api import Browser, Page, sync_playwright

CHROMIUM = os.environ.get("CMRT_CHROMIUM", "/usr/bin/chromium")
VIEWPORT = {"width": 1280, "height": 900}


@pytest.fixture(scope="session")
def browser() -> Iterator[Browser]:
    if not os.path.exists(CHROMIUM):
        pytest.fail(f"no Chromium at {CHROMIUM}: run `make setup` (it installs Debian's chromium)")
    with sync_playwright() as p:
        b = p.chromium.launch(executable_path=CHROMIUM, args=["--no-sandbox"])
        yield b
        b.close()


def _page(browser: Browser, offline: bool) -> Iterator[Page]:
    ctx = browser.new_context(viewport=VIEWPORT, offline=offline)
    page = ctx.new_page()
    errors: list[str] = []
    page.on("console", lambda m: errors.append(f"console.{m.type}: {m.text}")
            if m.type == "error" else None)
    page.on("pageerror", lambda e: errors.append(f"pageerror: {e}"))
    page.errors = errors  # type: ignore[attr-defined]
    yield page
    ctx.close()


@pytest.fixture
def page(browser: Browser) -> Iterator[Page]:
    yield from _page(browser, offline=False)


@pytest.fixture
def offline_page(browser: Browser) -> Iterator[Page]:
    yield from _page(browser, offline=True)

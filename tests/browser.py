"""Shared headless-browser launch for browser tests: Playwright driving Debian's chromium.

Playwright cannot download its own browser here (no internet on the build machines), so it
drives the system ``/usr/bin/chromium`` (``apt-get install chromium``; ``.ci/run`` does it).
Tests that need it call :func:`require_chromium` and are skipped with the reason when the
browser or the ``playwright`` package is absent.

:func:`offline_page` opens a page that may load ``file://`` URLs only: every other request
is aborted and recorded, so a test can assert that nothing tried to reach another host.
Console errors and uncaught page errors are recorded too.
"""

from __future__ import annotations

from collections.abc import Iterator
from contextlib import contextmanager
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import pytest

if TYPE_CHECKING:
    from playwright.sync_api import Page

CHROMIUM_PATH = Path("/usr/bin/chromium")

#: Flags for a quiet, offline headless chromium (no sandbox: tests may run as root in CI).
CHROMIUM_ARGS = (
    "--headless",
    "--no-sandbox",
    "--disable-gpu",
    "--disable-background-networking",
    "--disable-component-update",
    "--no-first-run",
    "--disable-sync",
)


def require_chromium() -> None:
    """Skip the calling test with a clear reason when chromium or playwright is missing."""
    if not CHROMIUM_PATH.exists():
        pytest.skip(
            f"browser test needs {CHROMIUM_PATH} (apt-get install -y chromium); not installed"
        )
    pytest.importorskip("playwright.sync_api", reason="browser test needs the playwright package")


@dataclass
class PageLog:
    """What a page did: console errors, page errors, and blocked (non-file) requests."""

    console_errors: list[str] = field(default_factory=list)
    page_errors: list[str] = field(default_factory=list)
    blocked_requests: list[str] = field(default_factory=list)


@contextmanager
def offline_page(
    viewport: tuple[int, int] = (1100, 900), allowed_origin: str | None = None
) -> Iterator[tuple[Page, PageLog]]:
    """A fresh chromium page that may load ``file://`` URLs only, and URLs of
    ``allowed_origin`` (e.g. ``http://127.0.0.1:8123``, the daemon under test) when given.

    Yields
    ------
    (page, log)
        The Playwright page and the :class:`PageLog` it fills while the block runs.
    """
    from playwright.sync_api import Route, sync_playwright

    log = PageLog()
    allowed = ("file://",) if allowed_origin is None else ("file://", allowed_origin + "/")

    def gate(route: Route) -> None:
        url = route.request.url
        if url.startswith(allowed) or url.startswith(("blob:", "data:")):
            route.continue_()
        else:
            log.blocked_requests.append(url)
            route.abort()

    def on_console(msg: Any) -> None:
        if msg.type == "error":
            log.console_errors.append(msg.text)

    with sync_playwright() as pw:
        browser = pw.chromium.launch(
            executable_path=str(CHROMIUM_PATH), headless=True, args=list(CHROMIUM_ARGS)
        )
        try:
            context = browser.new_context(
                viewport={"width": viewport[0], "height": viewport[1]},
                offline=allowed_origin is None,
                accept_downloads=True,
            )
            context.route("**/*", gate)
            page = context.new_page()
            page.on("console", on_console)
            page.on("pageerror", lambda exc: log.page_errors.append(str(exc)))
            yield page, log
        finally:
            browser.close()

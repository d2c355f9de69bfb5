"""A real browser for the map page's tests: Debian's Chromium driven by Playwright (its Python
package, with the system browser: Playwright's own browser download is not used).

`make test` installs Chromium with apt-get when it runs as root (CI does) and it is missing;
without Chromium or Playwright these tests are skipped, saying why. ``NAVSVC_CHROMIUM`` names
another Chromium binary. ``NAVSVC_SCREENSHOTS=docs/img`` also writes the README's screenshots.
"""

from __future__ import annotations

import os
import shutil
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

CANDIDATES = ("chromium", "chromium-browser", "google-chrome", "google-chrome-stable")


@pytest.fixture()
def db(sample_db: Path, tmp_path: Path) -> Path:
    """A private copy of the sample map, for a test that starts its own server."""
    copy = tmp_path / "monaco.db"
    shutil.copy(sample_db, copy)
    return copy


def chromium_path() -> str | None:
    named = os.environ.get("NAVSVC_CHROMIUM")
    if named:
        return named
    return next((path for name in CANDIDATES if (path := shutil.which(name))), None)


@pytest.fixture(scope="module")
def browser() -> Iterator[Any]:
    sync_api = pytest.importorskip("playwright.sync_api",
                                   reason="Playwright is not installed (pip install playwright)")
    executable = chromium_path()
    if executable is None:
        pytest.skip("no Chromium installed (apt-get install chromium; make test does it as "
                    "root)")
    with sync_api.sync_playwright() as playwright:
        launched = playwright.chromium.launch(
            executable_path=executable, headless=True,
            args=["--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage"])
        yield launched
        launched.close()


@pytest.fixture()
def page(browser: Any) -> Iterator[Any]:
    context = browser.new_context(viewport={"width": 1280, "height": 800})
    page = context.new_page()
    errors: list[str] = []
    page.on("pageerror", lambda exc: errors.append(str(exc)))
    page.errors = errors
    yield page
    context.close()
    assert not errors, f"JavaScript errors on the page: {errors}"


def screenshot(page: Any, name: str, tmp_path: Path) -> Path:
    """A PNG of the page: in tmp_path, and in $NAVSVC_SCREENSHOTS too when set."""
    path = tmp_path / name
    page.screenshot(path=str(path))
    folder = os.environ.get("NAVSVC_SCREENSHOTS")
    if folder:
        Path(folder).mkdir(parents=True, exist_ok=True)
        shutil.copy(path, Path(folder) / name)
    return path

"""Browser tests of hdrview: Python playwright driving Debian's chromium with swiftshader WebGL.

Skipped (with the reason) when chromium or playwright is absent; CI installs both. The inspector
runs in-process on a free port so the tests can read the server's state next to the page's.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from pathlib import Path

import pytest

from hdrview.app import InspectorApp, create_app

from ..hdrview._brackets import DEMO_DIR, write_png_bracket

CHROMIUM = Path("/usr/bin/chromium")
ARTIFACTS = Path(__file__).resolve().parents[2] / "test-artifacts"
CHROMIUM_ARGS = [
    "--no-sandbox",
    "--disable-gpu",
    "--enable-unsafe-swiftshader",
    "--disable-dev-shm-usage",
]

pytestmark = pytest.mark.e2e


@pytest.fixture(scope="session")
def browser() -> Iterator[object]:
    if not CHROMIUM.exists():
        pytest.skip(
            f"browser tests need Debian's chromium at {CHROMIUM} (apt-get install chromium)"
        )
    sync_api = pytest.importorskip("playwright.sync_api", reason="playwright is not installed")
    with sync_api.sync_playwright() as p:
        b = p.chromium.launch(executable_path=str(CHROMIUM), args=CHROMIUM_ARGS)
        try:
            yield b
        finally:
            b.close()


@pytest.fixture(scope="module")
def e2e_root(tmp_path_factory: pytest.TempPathFactory) -> Path:
    root = tmp_path_factory.mktemp("e2e-root")
    write_png_bracket(root / "small")
    (root / "junk").mkdir()
    (root / "junk" / "a.png").write_text("this is not an image")
    (root / "junk" / "b.png").write_text("neither is this")
    return root


@pytest.fixture(scope="module")
def inspector(e2e_root: Path) -> Iterator[InspectorApp]:
    """The app as ``hdrview`` starts it with no arguments: it opens the demo bracket.

    When the bundled demo (``assets/demo``) is missing, a small synthetic bracket stands in.
    """
    demo = DEMO_DIR if DEMO_DIR.is_dir() else e2e_root / "small"
    app = create_app([], port=0, root=str(e2e_root), verbose=False, demo_dir=demo)
    try:
        yield app
    finally:
        app.stop()
        app.server.stop()


@pytest.fixture(scope="module")
def page(browser: object, inspector: InspectorApp) -> Iterator[object]:
    ARTIFACTS.mkdir(exist_ok=True)
    ctx = browser.new_context(viewport={"width": 1600, "height": 1000}, accept_downloads=True)
    pg = ctx.new_page()
    pg.goto(inspector.url)  # with the access token (hdrview.guard)
    deadline = time.monotonic() + 30
    while not inspector.server.get_clients():
        if time.monotonic() > deadline:
            pytest.fail("the page never connected to the server (WebGL unavailable?)")
        time.sleep(0.05)
    try:
        yield pg
    finally:
        ctx.close()


@pytest.fixture(scope="module")
def view(page: object, inspector: InspectorApp):
    """The page's own view (its bracket, controls and notifications) on the server."""
    deadline = time.monotonic() + 30
    while not inspector.page_views():
        if time.monotonic() > deadline:
            pytest.fail("no view was built for the page")
        time.sleep(0.05)
    return inspector.page_views()[0]

"""An inspector on a free port with a small synthetic bracket under its root."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest
import viser

from hdrview.app import InspectorApp
from hdrview.view import ClientView

from ._brackets import write_png_bracket


@pytest.fixture
def bracket_root(tmp_path: Path) -> Path:
    root = tmp_path / "root"
    write_png_bracket(root / "bracket")
    return root


@pytest.fixture
def app(bracket_root: Path) -> Iterator[ClientView]:
    """One page's view (without a browser) of an inspector on a free port."""
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    inspector = InspectorApp(server, root=bracket_root, demo_dir=None)
    try:
        yield inspector.headless_view()
    finally:
        inspector.stop()
        server.stop()

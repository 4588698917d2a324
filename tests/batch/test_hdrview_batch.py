"""``hdrview --batch OUTDIR``: the batch's brackets worst first, in the terminal and as a
dropdown on the page; the worst opens first, choosing another opens its frames."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdrcore.batch import BracketRecord, write_index

viser = pytest.importorskip("viser")

from hdrview.app import InspectorApp, main  # noqa: E402
from hdrview.batch import add_batch_panel, batch_listing, load_batch  # noqa: E402


def _records(folder: Path) -> list[BracketRecord]:
    out = []
    for k, (status, score) in enumerate(
        (("ok", 0.9), ("failed", 0.0), ("warning", 0.4), ("ok", 0.5))
    ):
        files = []
        for j in range(2):
            p = folder / f"b{k}_{j}.png"
            p.write_bytes(b"x")
            files.append(str(p))
        out.append(
            BracketRecord(
                f"b{k}",
                tuple(files),
                status,
                quality={"score": score},
                reason="broken frame" if status == "failed" else "",
            )
        )
    return out


def test_listing_is_worst_first(tmp_path):
    write_index(tmp_path, _records(tmp_path))
    batch = load_batch(tmp_path)
    assert [r.name for r in batch] == ["b1", "b2", "b3", "b0"]
    lines = batch_listing(batch).splitlines()
    assert "failed" in lines[1] and "broken frame" in lines[1] and "b0" in lines[-1]


def test_page_opens_the_worst_then_the_chosen(tmp_path):
    write_index(tmp_path, _records(tmp_path))
    batch = load_batch(tmp_path)
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    app = InspectorApp(server, root=tmp_path, demo_dir=None, batch=batch)
    try:
        paths, label = app.default_paths()
        assert label == "b1" and [str(p) for p in paths] == list(batch[0].files)
        view = app.headless_view()
        opened = []
        view.request_paths = lambda paths, label="", client=None: (
            opened.append((list(paths), label)) or True
        )
        dropdown = add_batch_panel(view, batch)
        assert dropdown.value.startswith("1. failed")
        dropdown.value = dropdown.options[2]
        assert opened and opened[-1] == (list(batch[2].files), batch[2].name)
    finally:
        app.stop()
        server.stop()


def test_bad_batch_folder_is_one_line(tmp_path, capsys):
    assert main(["--batch", str(tmp_path), "--port", "0"]) == 2
    err = capsys.readouterr().err
    assert "index.json" in err and "hdrcore batch" in err

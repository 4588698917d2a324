"""The inspector's white balance view (issue 15): a real pipeline result of a small simulated sRGB
bracket whose frames were shot with different white balances; the table shows each frame's gains
against the reference, whether they were divided out, and says so in words."""

from __future__ import annotations

import re
from collections.abc import Iterator
from pathlib import Path

import numpy as np
import pytest
import viser

from hdrcore.io import load_bracket, write_png
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket
from hdrview.panels.response import ResponsePanel
from hdrview.panels.white_balance import (
    WhiteBalancePanel,
    balance_of,
    gains_figure,
    verdict,
    white_balance_markdown,
)

TIMES = (1.0, 2.0, 4.0, 8.0, 16.0)
# frame 0 shot cooler (B/G +8 %, R/G -5 %), frame 4 warmer (R/G +6 %, B/G -7 %)
SHOT = {0: (0.95, 1.0, 1.08), 4: (1.06, 1.0, 0.93)}


def _write(folder: Path, seed: int = 3) -> Path:
    kw = dict(
        shape=(120, 180), exposure_times=TIMES, bits=8, response="srgb", noise_sigma=1.0, seed=seed
    )
    sim = simulate_bracket(scene="patches", **kw)
    folder.mkdir(parents=True, exist_ok=True)
    lines = []
    for k, t in enumerate(TIMES):
        frame = sim.frames[k]
        if k in SHOT:
            frame = simulate_bracket(sim.radiance * np.asarray(SHOT[k]), key=sim.key, **kw).frames[
                k
            ]
        write_png(folder / f"f{k}.png", np.asarray(frame).astype(np.uint8), force=True)
        lines.append(f"f{k}.png {t:g}")
    (folder / "exposure_times.txt").write_text("\n".join(lines) + "\n")
    return folder


@pytest.fixture(scope="module")
def runs(tmp_path_factory):
    """The bracket through the pipeline with the white balance switch on and off. The response
    is the bracket's own (sRGB): with both end frames re-balanced in opposite directions the
    recovered joint curve absorbs part of the casts into its channels (measured: frames 1 and 3
    then read 2.6 % / 3.7 % off, frames 0 and 4 under 1 %), which is the response's matter;
    here the view of what was measured is tested."""
    folder = _write(tmp_path_factory.mktemp("wb") / "bracket")
    bracket = load_bracket([folder], exposure_times=folder / "exposure_times.txt")
    kw = dict(registration_previews=False, response="srgb")
    on = Pipeline(bracket, PipelineParams(**kw)).run(until="merge")
    off = Pipeline(bracket, PipelineParams(**kw, white_balance=False)).run(until="merge")
    return bracket, on, off


@pytest.fixture(scope="module")
def gui() -> Iterator[viser.GuiApi]:
    server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
    try:
        yield server.gui
    finally:
        server.stop()


def _table(markdown: str) -> dict[int, tuple[str, str, str]]:
    """``{frame: (R/G cell, B/G cell, state)}`` from the panel's markdown table."""
    out = {}
    for line in markdown.splitlines():
        m = re.match(r"\| frame (\d+)[^|]*\| ([^|]*) \| ([^|]*) \| ([^|]*) \|$", line)
        if m:
            out[int(m.group(1))] = (m.group(2), m.group(3), m.group(4))
    return out


def _percent(cell: str) -> float:
    m = re.match(r"([+-]\d+\.\d) ± (\d+\.\d)$", cell)
    assert m, cell
    return float(m.group(1))


def _true_gain(k: int, ref: int) -> np.ndarray:
    """Frame ``k``'s R/G and B/G relative to the reference's, as % differences."""
    g = np.asarray(SHOT.get(k, (1.0, 1.0, 1.0))) / np.asarray(SHOT.get(ref, (1.0, 1.0, 1.0)))
    return 100.0 * (g[[0, 2]] - 1.0)


def test_the_table_shows_each_frames_gains_and_that_they_were_divided_out(runs, gui) -> None:
    bracket, on, _ = runs
    wb = balance_of(on)
    assert wb is not None and wb["applied"]
    ref = wb["reference"]
    assert ref not in SHOT  # the middle frame: both re-balanced frames differ from it
    panel = WhiteBalancePanel(gui)
    panel.show(bracket, on)
    rows = _table(panel.text.content)
    assert sorted(rows) == list(range(len(TIMES)))
    for k, (rg, bg, state) in rows.items():
        if k == ref:
            assert rg == bg == "0 (reference)" and state == "reference"
            continue
        shown = np.array([_percent(rg), _percent(bg)])
        # the gains the pipeline measured, as the table shows them, within 1 % of the truth
        np.testing.assert_allclose(shown, _true_gain(k, ref), atol=1.0)
        # the re-balanced frames differ; once one does, every measured frame is divided out
        assert state == ("differs: corrected" if k in SHOT else "corrected")
    assert panel.plot.visible and panel.figure is not None
    # the plot draws the same numbers (R/G, B/G, threshold lines)
    ys = np.array(panel.figure.data[0].y, dtype=float)
    np.testing.assert_allclose(ys[0], _true_gain(0, ref)[0], atol=1.0)
    text = panel.text.content
    assert "divided out of the merge" in text
    # a photographer's words: frame 0 is bluer and less red, frame 4 yellower and redder
    assert re.search(r"frame 0 \(1 s\) is \d+\.\d % bluer and \d+\.\d % less red than", text)
    assert re.search(
        r"frame 4 \(16 s\) is \d+\.\d % yellower \(less blue\) and \d+\.\d % redder", text
    )
    assert "; corrected (divided out of the merge)." in text


def test_switched_off_the_same_gains_are_reported_not_applied(runs, gui) -> None:
    bracket, on, off = runs
    wb_on, wb_off = balance_of(on), balance_of(off)
    assert wb_off is not None and not wb_off["applied"] and wb_off["differs"] == wb_on["differs"]
    panel = WhiteBalancePanel(gui)
    panel.show(bracket, off)
    rows_on = _table(WhiteBalancePanel(gui).text.content or "")
    assert rows_on == {}  # a fresh panel shows nothing before show()
    rows = _table(panel.text.content)
    ref = wb_off["reference"]
    for k in SHOT:
        rg, bg, state = rows[k]
        np.testing.assert_allclose([_percent(rg), _percent(bg)], _true_gain(k, ref), atol=1.0)
        assert state == "differs: measured only (switch off)"
    assert "**measured only**: the White balance switch is off" in panel.text.content
    assert "not corrected: the White balance switch is off" in verdict(wb_off, 0, "frame 0")
    assert "(not divided out)" in panel.figure.layout.title.text


def test_response_panel_carries_the_view_and_its_figure(runs, gui) -> None:
    bracket, on, _ = runs
    panel = ResponsePanel(gui)
    panel.show(bracket, on, {})
    assert "White balance per frame" in panel.white_balance.text.content
    names = [n for n, _ in panel.bundle_files()]
    assert "white-balance.plotly.json" in names
    panel.show(None, None, {})
    assert not panel.white_balance.plot.visible and panel.white_balance.text.content == ""


def test_an_unmeasured_frame_is_said_so_and_left_blank(gui) -> None:
    """A black frame (nothing well exposed in it and its neighbour) cannot be measured."""
    from hdrcore.merge.colour_check import srgb_decode_lut
    from hdrcore.merge.white_balance import measure_white_balance

    sim = simulate_bracket(
        scene="patches",
        shape=(120, 180),
        exposure_times=TIMES,
        bits=8,
        response="srgb",
        noise_sigma=1.0,
        seed=3,
    )
    frames = [np.asarray(f).astype(np.uint8) for f in sim.frames]
    frames[0] = np.zeros_like(frames[0])
    fb = measure_white_balance(
        frames, np.tile(srgb_decode_lut(255), (3, 1)), max_level=255, reference=2
    )
    assert fb.unmeasured == (0,)
    wb = fb.to_json()
    rows = _table(white_balance_markdown(wb, None))
    assert rows[0] == ("—", "—", "not measured")
    assert "white balance not measured" in verdict(wb, 0, "frame 0")
    fig = gains_figure(wb, None)
    assert fig.data[0].y[0] is None and len(fig.data[0].y) == len(TIMES)

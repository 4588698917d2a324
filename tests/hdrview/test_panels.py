"""Panels draw the pipeline's real result objects (a synthetic RAW bracket with known truth,
written as DNG and run through :class:`hdrcore.pipeline.Pipeline`) without errors."""

from __future__ import annotations

import dataclasses
import io
import zipfile

import numpy as np
import pytest

from hdrcore.exposure.result import INLIER, OUTLIER, SATURATED, UNDER
from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket, write_bracket
from hdrview.panels.masks import pixel_classes
from hdrview.panels.result import exr_bytes, preview_png_bytes
from hdrview.view import ClientView


@pytest.fixture(scope="module")
def sim():
    return simulate_bracket(
        scene="window",
        shape=(128, 192),
        exposure_times=(1.0, 4.0, 16.0),
        bits=12,
        response="linear",
        noise_sigma=1.0,
        seed=2,
        max_shift=2.0,
        max_rotation_deg=0.3,
        keep_linear=True,
    )


@pytest.fixture(scope="module")
def stage_result(sim, tmp_path_factory):
    """A real :class:`hdrcore.pipeline.PipelineResult` of the simulated bracket."""
    out = tmp_path_factory.mktemp("panels") / "dng"
    write_bracket(out, sim, fmt="dng")
    bracket = load_bracket([out])
    return Pipeline(bracket, PipelineParams()).run()


@pytest.fixture
def sim_bracket(stage_result):
    return stage_result.bracket


@pytest.fixture
def viewer(app: ClientView) -> ClientView:
    return app


def test_level_classes_follow_the_equations(stage_result) -> None:
    pair = stage_result.exposures_histogram.pairs[0]
    for which in ("dark", "bright"):
        table = pair.level_classes(which)
        assert table.shape == (3, pair.max_level + 1)
        assert (table[:, int(np.ceil(pair.saturation)) :] == SATURATED).all()
        assert (table[:, : int(pair.noise_floor) + 1] == UNDER).all()
        assert (table == INLIER).any()
    # Every inlier equation from the dark frame marks its level as an inlier.
    eq = pair.equations
    inside = (eq.level > pair.noise_floor + 1) & (eq.level < pair.saturation - 1)
    sel = (eq.direction == 0) & pair.inlier_mask & inside
    table = pair.level_classes("dark")
    assert (table[eq.channel[sel], np.floor(eq.level[sel]).astype(int)] == INLIER).all()
    sel = (eq.direction == 0) & ~pair.inlier_mask & inside
    assert (table[eq.channel[sel], np.floor(eq.level[sel]).astype(int)] == OUTLIER).all()


def test_pixel_classes_take_most_channels_and_saturated_if_any() -> None:
    table = np.array([[INLIER, OUTLIER, SATURATED, UNDER]] * 3, np.int8)
    levels = np.array(
        [[[0, 0, 0], [0, 1, 0], [0, 1, 1], [0, 1, 2], [0, 1, 3], [3, 3, 0]]], np.uint16
    )
    # all inlier; 2 of 3 inlier; 2 of 3 outlier; one saturated channel; a three-way tie goes
    # to the most severe (under); 2 of 3 under
    assert pixel_classes(levels, table).tolist() == [
        [INLIER, INLIER, OUTLIER, SATURATED, UNDER, UNDER]
    ]
    grey = np.array([[[1], [3]]], np.uint16)
    assert pixel_classes(grey, table[:1]).tolist() == [[OUTLIER, UNDER]]


def test_masks_say_the_equation_counts_of_the_btf_tab(viewer, stage_result, sim_bracket) -> None:
    from hdrview.panels.masks import MasksPanel, equation_counts

    panel = MasksPanel(viewer.gui)
    panel.show(sim_bracket, stage_result, {"pair": 0})
    pair = stage_result.exposures_histogram.pairs[0]
    text = equation_counts(pair, 3)
    assert text.startswith(f"{pair.n_inliers} of {pair.n_equations} equations")
    per = [int(x.split("/")[0].split()[-1]) for x in text[text.index("(") + 1 : -1].split(",")]
    assert sum(per) == pair.n_inliers
    assert text in panel.summary.content


@pytest.mark.parametrize("layer", ["tonemapped", "provenance", "clipping", "ghosts", "deghosted"])
@pytest.mark.parametrize("overlay", ["red/cyan", "difference (eq. 7)"])
def test_every_panel_draws(viewer, stage_result, sim_bracket, layer, overlay) -> None:
    view = {"pair": 1, "layer": layer, "overlay": overlay}
    for panel in (
        viewer.btf_panel,
        viewer.masks_panel,
        viewer.registration_panel,
        viewer.result_panel,
        viewer.diagnostics_panel,
    ):
        panel.show(sim_bracket, stage_result, view)
    assert "Pair 1→2" in viewer.btf_panel.summary.content
    assert viewer.btf_panel.scatter.visible and viewer.btf_panel.transfer.visible
    names = [t.get("name", "") for t in viewer.btf_panel.scatter.figure.to_dict()["data"]]
    assert any(n.startswith("inliers") for n in names)
    assert any(n.startswith("converged k") for n in names)
    assert any(n.startswith("initial k0") for n in names)
    assert any(n.startswith("EXIF") for n in names)
    assert viewer.masks_panel.dark.visible and viewer.masks_panel.bright.visible
    assert viewer.masks_panel.dark.image.dtype == np.uint8
    assert viewer.result_panel.image.visible
    assert viewer.result_panel.image.image.ndim == 3
    table = viewer.diagnostics_panel.table.content
    assert "1→2" in table and "EXIF ratio" in table
    assert "Merged 3 of 3 frames" in viewer.diagnostics_panel.verdicts.content
    assert "dx =" in viewer.registration_panel.summary.content
    if overlay == "red/cyan":  # at full resolution, from the frames
        assert viewer.registration_panel.full.visible
        assert viewer.registration_panel.full.image.shape[1] >= 128
    else:
        assert viewer.registration_panel.before.visible


def test_deghosted_layer_paints_the_filled_pixels(viewer, stage_result, sim_bracket) -> None:
    """Without deghosting the layer says how to get it; with it the filled pixels are painted
    over the dimmed preview and counted."""
    view = {"pair": 0, "layer": "deghosted", "overlay": "red/cyan"}
    viewer.result_panel.show(sim_bracket, stage_result, view)
    assert "tick Deghost" in viewer.result_panel.summary.content
    merged = stage_result.merge
    filled = np.zeros(merged.shape, bool)
    filled[: merged.shape[0] // 2] = True
    with_deghost = dataclasses.replace(
        stage_result, merge=dataclasses.replace(merged, deghosted=filled)
    )
    viewer.result_panel.show(sim_bracket, with_deghost, view)
    summary = viewer.result_panel.summary.content
    assert "deghosted: filled from one frame" in summary and "50.00% of the pixels" in summary
    img = viewer.result_panel._images["deghosted"]
    top, bottom = img[: img.shape[0] // 4], img[-img.shape[0] // 4 :]
    assert (top == (0, 200, 255)).all(axis=-1).mean() > 0.9
    assert (bottom == (0, 200, 255)).all(axis=-1).mean() < 0.01


def test_exports_and_bundle(viewer, stage_result, sim_bracket) -> None:
    view = {"pair": 0, "layer": "provenance", "overlay": "red/cyan"}
    for panel in (
        viewer.btf_panel,
        viewer.masks_panel,
        viewer.registration_panel,
        viewer.result_panel,
        viewer.diagnostics_panel,
    ):
        panel.show(sim_bracket, stage_result, view)
    assert exr_bytes(stage_result)[:4] == b"\x76\x2f\x31\x01"  # OpenEXR magic
    assert preview_png_bytes(stage_result)[:8] == b"\x89PNG\r\n\x1a\n"
    viewer.session.result = stage_result
    names = zipfile.ZipFile(io.BytesIO(viewer.bundle_bytes())).namelist()
    assert "report.json" in names
    assert "btf-equations.plotly.json" in names
    assert any(n.startswith("mask-dark") for n in names)
    assert "result-provenance.png" in names
    # The plots as pictures too (no kaleido or browser needed), next to their plotly JSON.
    assert "btf-equations.png" in names and "registration-costs.png" in names
    from PIL import Image

    with zipfile.ZipFile(io.BytesIO(viewer.bundle_bytes())) as zf:
        png = Image.open(io.BytesIO(zf.read("btf-equations.png")))
        assert png.size == (960, 600)
        rgb = np.asarray(png.convert("RGB")).reshape(-1, 3)
        assert len(np.unique(rgb, axis=0)) > 3  # something was drawn


def test_waiting_notes_without_a_result(viewer, sim_bracket) -> None:
    view = {"pair": 0, "layer": "tonemapped", "overlay": "red/cyan"}
    viewer.btf_panel.show(sim_bracket, None, view)
    viewer.masks_panel.show(sim_bracket, None, view)
    assert "Waiting" in viewer.btf_panel.summary.content
    assert not viewer.masks_panel.dark.visible


def test_btf_panel_shows_the_histogram_fit_and_the_registered_ratio(viewer, sim_bracket) -> None:
    from pathlib import Path

    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline

    demo = Path(__file__).resolve().parents[2] / "assets" / "demo"
    b = load_bracket([demo])
    res = Pipeline(b).run(until="overlap_ratios")
    assert res.exposures.method == "registered pixels"
    viewer.btf_panel.show(b, res, {"pair": 1})
    text = viewer.btf_panel.summary.content
    assert "After registration" in text and "registered pixels" in text
    assert f"({res.exposures_histogram.method})" in text
    names = [t.get("name", "") for t in viewer.btf_panel.scatter.figure.to_dict()["data"]]
    assert any(n.startswith("registered pixels") for n in names)
    assert viewer.btf_panel.transfer.visible
    viewer.masks_panel.show(b, res, {"pair": 1})
    assert viewer.masks_panel.dark.visible


def test_exports_cropped_to_the_common_area(viewer, stage_result, tmp_path) -> None:
    """The Export folder's 'Crop to common area': the EXR and the preview hold only the
    rectangle every frame covers, as ``hdrcore merge --crop common`` writes them."""
    from PIL import Image

    from hdrcore.export import common_crop
    from hdrcore.io import read_exr

    x0, y0, x1, y1 = common_crop(stage_result)
    h, w = stage_result.radiance.shape[:2]
    assert (x1 - x0, y1 - y0) != (w, h)  # the simulated bracket moved: a crop to make
    path = tmp_path / "c.exr"
    path.write_bytes(exr_bytes(stage_result, crop=True))
    rgb, attrs = read_exr(path)
    assert rgb.shape[:2] == (y1 - y0, x1 - x0)
    assert attrs["hdrview"]["crop"] == [x0, y0, x1, y1]
    full = Image.open(io.BytesIO(preview_png_bytes(stage_result)))
    cut = Image.open(io.BytesIO(preview_png_bytes(stage_result, crop=True)))
    assert cut.size[0] <= full.size[0] and cut.size[1] <= full.size[1]
    assert cut.size != full.size
    assert viewer.crop_checkbox.value is False  # off unless asked


def test_exposure_times_read_as_a_camera_shows_them() -> None:
    # a times file's decimals (the Xperia bracket's 0.06666666667) were shown as the exact
    # fraction 6666666667/100000000000 s in the frames table
    from fractions import Fraction

    from hdrview.panels.frames import _seconds

    assert _seconds(Fraction(6666666667, 100000000000)) == "1/15 s"
    assert _seconds(Fraction(1, 803)) == "1/803 s"
    assert _seconds(0.125) == "1/8 s"
    assert _seconds(0.3) == "0.3 s"  # not 1/3
    assert _seconds(8) == "8 s"


@pytest.mark.parametrize("with_lut", [False, True])
def test_overlay_samples_read_the_linearised_plane_bilinearly(with_lut: bool) -> None:
    # the registration overlay reads its points from the four neighbours' linear values,
    # as scipy's map_coordinates reads the whole linearised plane (which it no longer makes)
    from types import SimpleNamespace

    from scipy.ndimage import map_coordinates

    from hdrview.panels.registration import _linear_green, _sample_green

    rng = np.random.default_rng(0)
    lut = np.sort(rng.random((3, 256)), axis=1).astype(np.float32) if with_lut else None
    frame = SimpleNamespace(
        levels=rng.integers(0, 256, (50, 70, 3)).astype(np.uint8), max_level=255
    )
    x, y = rng.uniform(-3, 73, 5000), rng.uniform(-3, 53, 5000)
    x[:5], y[:5] = [0, 69, 69, 0, 34.5], [0, 49, 0, 49, 49]  # corners and the last row
    plane = _linear_green(frame, lut)  # type: ignore[arg-type]
    want = map_coordinates(plane, [y, x], order=1, mode="constant", cval=0.0)
    got = _sample_green(frame, lut, x, y)  # type: ignore[arg-type]
    assert np.abs(got - want).max() < 1e-6
    assert np.count_nonzero(got == 0) > 100  # points outside read 0


def test_registration_overlays_are_not_drawn_again_for_a_kept_registration(app) -> None:
    """A saturation step that keeps the registration leaves its overlays as drawn (drawing
    them again held up the merge by about 0.1 s a step at 24 MP); a new zoom, a new pair or a
    new registration draws them."""
    panel = app.registration_panel
    drawn: list[int] = []
    original = panel._show

    def spy(*args, **kwargs):
        drawn.append(1)
        return original(*args, **kwargs)

    panel._show = spy  # type: ignore[method-assign]
    assert app.request_path("bracket") and app.wait_idle(120)
    result = app.session.result
    assert result is not None and result.registration is not None
    assert len(drawn) >= 1
    # one-level steps down from the default: most keep the registration (its levels snap to
    # the bracket's ladder); such a step draws nothing in this panel
    kept = 0
    for value in np.floor(result.saturation) - np.arange(1, 6):
        before, previous = len(drawn), app.session.result
        app.set_control("saturation", float(value))
        assert app.wait_idle(120)
        after = app.session.result
        assert after is not None and after is not previous
        if after.registration is previous.registration:
            kept += 1
            assert len(drawn) == before  # the same overlays: not drawn again
        else:  # drawn with the registration, again once the response used is known
            assert len(drawn) > before
    assert kept >= 1
    before = len(drawn)
    panel._redraw()  # as the panel's own controls do
    assert len(drawn) == before
    panel.zoom.value = panel.zoom.options[-1]  # a new zoom: drawn
    panel._redraw()
    assert len(drawn) == before + 1
    count = len(drawn)
    app.set_control("threshold", 0.2)  # a new registration: drawn
    assert app.wait_idle(120)
    assert app.session.result.registration is not after.registration
    assert len(drawn) > count


def test_the_merge_weighting_is_said_in_words_with_its_term_on_hover() -> None:
    import html

    from hdrcore.merge.weights import WEIGHTS
    from hdrview.panels.result import WEIGHTING_WORDS, weighting_words

    assert set(WEIGHTS) <= set(WEIGHTING_WORDS)  # every weighting of the library has words
    for name in WEIGHTS:
        shown = weighting_words(name)
        words, paper = WEIGHTING_WORDS[name]
        assert shown.startswith('<abbr title="') and shown.endswith("</abbr>")
        title = shown[len('<abbr title="') : shown.index('">')]
        assert html.unescape(title) == f"{paper} ({name})"  # quotes and apostrophes escaped
        assert '"' not in title and "'" not in title
        assert html.unescape(shown[shown.index('">') + 2 : -len("</abbr>")]).lower() == words
    assert "hat-noise-aware" in weighting_words("hat-noise-aware")


def test_a_pair_never_registered_reads_a_dash_not_nan(stage_result) -> None:
    """A saturated pair (too few well-exposed pixels) has no overlap: the summary says "—"
    where it once said "overlap nan%"."""
    from hdrview.panels._draw import pct
    from hdrview.panels.registration import motion_summary

    pair = dataclasses.replace(
        stage_result.registration.pairs[0], overlap=float("nan"), status="saturated"
    )
    text = motion_summary(pair)
    assert "nan" not in text.lower()
    assert "overlap —," in text
    assert pct(0.0123) == "1.2%" and pct(None) == "—" and pct(float("inf")) == "—"


def test_the_cost_plot_draws_one_line_per_image_size(stage_result) -> None:
    """Each pyramid level has its own cost scale: one trace per level, named by its size, so a
    finer level starting higher does not read as the search getting worse."""
    from hdrview.panels.registration import cost_figure

    pair = dataclasses.replace(
        stage_result.registration.pairs[0],
        cost_history=(4.7e-4, 3.4e-4, 3.3e-4, 5.7e-4, 5.5e-4, 2.5e-3, 2.4e-3),
        level_history=(2, 2, 2, 1, 1, 0, 0),
    )
    fig = cost_figure(pair)
    assert [t.name for t in fig.data] == ["1/4 size", "1/2 size", "full size"]
    assert [list(t.x) for t in fig.data] == [[0, 1, 2], [3, 4], [5, 6]]
    assert list(fig.data[2].y) == [2.5e-3, 2.4e-3]


def test_the_pairs_table_gives_both_inlier_counts_when_ratios_were_measured_again(
    stage_result,
) -> None:
    from hdrview.panels.diagnostics import pairs_table

    r = stage_result
    hist, used = r.exposures_histogram, r.exposures
    assert used is not hist  # the simulated hand-held bracket's ratios measured again
    table = pairs_table(used, r.registration, r.bracket, hist)
    assert "inlier equations (histograms → registered pixels)" in table
    for h, u in zip(hist.pairs, used.pairs, strict=True):
        assert f"{h.n_inliers}/{h.n_equations} → {u.n_inliers}/{u.n_equations}" in table
    plain = pairs_table(hist, r.registration, r.bracket, hist)
    assert "→ registered" not in plain


def test_the_summary_says_exif_when_every_pair_used_it(stage_result) -> None:
    from hdrview.panels.diagnostics import summary_line

    r = stage_result
    n = len(r.bracket) - 1
    every = "estimated; EXIF for pairs " + ", ".join(f"{k}-{k + 1}" for k in range(n))
    line = summary_line(dataclasses.replace(r, times_source=every))
    assert "exposure times: EXIF for every pair" in line and "estimated" not in line
    some = dataclasses.replace(r, times_source="estimated; EXIF for pairs 0-1")
    assert "exposure times: estimated; EXIF for pair 0-1" in summary_line(some)
    if n > 2:
        two = dataclasses.replace(r, times_source="estimated; EXIF for pairs 0-1, 1-2")
        assert "exposure times: estimated; EXIF for pairs 0-1, 1-2" in summary_line(two)


def test_times_from_a_times_file_are_not_called_exif(stage_result) -> None:
    """The memorial's scans get their times from a file: the words say so, not "EXIF"."""
    from hdrview.panels.diagnostics import times_words

    r = stage_result
    frames = tuple(
        dataclasses.replace(f, meta=dataclasses.replace(f.meta, exposure_time_source="times-file"))
        for f in r.bracket.frames
    )
    filed = dataclasses.replace(
        r,
        bracket=dataclasses.replace(r.bracket, frames=frames),
        times_source="estimated; EXIF for pairs 0-1",
    )
    assert times_words(filed) == "estimated; the times file for pair 0-1"
    assert "EXIF" not in times_words(dataclasses.replace(filed, times_source="exif"))


def test_the_status_line_says_the_times_as_the_summary_does(viewer, stage_result) -> None:
    from hdrview.panels.diagnostics import times_words

    n = len(stage_result.bracket) - 1
    every = "estimated; EXIF for pairs " + ", ".join(f"{k}-{k + 1}" for k in range(n))
    r = dataclasses.replace(stage_result, times_source=every)
    assert times_words(r).startswith("EXIF for every pair")
    viewer.session.bracket = r.bracket
    status = viewer.status_markdown(r)
    assert "times = EXIF for every pair" in status and "times = estimated" not in status


def test_the_btf_tab_says_which_ratio_the_merge_used(viewer, stage_result, sim_bracket) -> None:
    """Where the pipeline fell back to the EXIF ratio (an unreliable estimate), the BTF tab
    says so instead of "the merge uses this estimate" (the Pixel 7's five pairs)."""
    from hdrview.panels.btf import BtfPanel

    panel = BtfPanel(viewer.gui)
    panel.show(sim_bracket, stage_result, {"pair": 1})
    assert "The merge uses this estimate." in panel.summary.content
    fell = dataclasses.replace(stage_result, times_source="estimated; EXIF for pairs 1-2")
    panel.show(sim_bracket, fell, {"pair": 1})
    assert "The merge uses the EXIF ratio" in panel.summary.content
    assert "The merge uses this estimate." not in panel.summary.content
    panel.show(sim_bracket, fell, {"pair": 0})
    assert "The merge uses this estimate." in panel.summary.content


def test_a_verdict_repeated_for_many_pairs_is_one_folded_line(stage_result) -> None:
    from hdrcore.diagnose import Verdict
    from hdrview.panels.diagnostics import GROUP_AT, verdicts_markdown

    many = tuple(
        Verdict("ratio-uncertain", "warning", f"The ratio of pair {k} <is> off", (k, k + 1))
        for k in range(GROUP_AT)
    )
    few = (Verdict("channels-disagree", "warning", "channels of pair 7", (7, 8)),)
    other = (Verdict("darkest-clipped", "warning", "clipped", ()),)
    text = verdicts_markdown(dataclasses.replace(stage_result, verdicts=many + few + other))
    folded = [line for line in text.splitlines() if "<details>" in line]
    assert len(folded) == 1
    line = folded[0]
    assert f"for {GROUP_AT} pairs (0-1, 1-2, 2-3)" in line
    assert line.count("<li>") == GROUP_AT and "&lt;is&gt;" in line  # each message, escaped
    assert "- <span title='channels-disagree'>channels of pair 7</span>" in text
    assert "clipped" in text
    # below GROUP_AT, one line per verdict as before
    text = verdicts_markdown(dataclasses.replace(stage_result, verdicts=many[:1]))
    assert "<details>" not in text and "The ratio of pair 0" in text


def test_every_pair_status_has_a_folded_title() -> None:
    from hdrview.panels.diagnostics import _group_title

    assert _group_title("ratio-no-signal") == "The exposure ratio is unreliable (no-signal)"
    assert _group_title("no-overlap") and _group_title("registration-failed")
    assert _group_title("darkest-clipped") is None and _group_title("times-fallback") is None


def test_btf_outliers_are_drawn_beneath_the_inliers(stage_result) -> None:
    """On a phone's locally tone-mapped pair most equations are 3V outliers: their crosses,
    drawn last and large, hid the inliers the fit used. They are drawn first, lighter."""
    import numpy as np

    from hdrview.panels.btf import equations_figure

    pair = stage_result.exposures_histogram.pairs[0]
    inl = np.asarray(pair.inlier_mask, bool)
    inl[::3] = False  # some outliers, whatever the fit found
    fig = equations_figure(dataclasses.replace(pair, inlier_mask=inl), None)
    names = [t.name for t in fig.data]
    assert names[0] == "outliers (3V)" and any(n.startswith("inliers") for n in names[1:])
    assert fig.data[0].marker.opacity < 1

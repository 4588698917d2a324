"""The cached pipeline: stages, re-use, parameters, report, verdicts."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.synthetic import simulate_bracket, write_bracket

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "assets" / "demo"


@pytest.fixture(scope="module")
def handheld_png(tmp_path_factory: pytest.TempPathFactory) -> Path:
    sim = simulate_bracket(
        scene="window",
        shape=(160, 240),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        max_shift=4,
        max_rotation_deg=0.5,
        seed=3,
    )
    out = tmp_path_factory.mktemp("hh")
    write_bracket(out, sim, fmt="png")
    return out


@pytest.fixture(scope="module")
def demo_result():
    b = load_bracket([DEMO])
    pipe = Pipeline(b)
    return pipe, pipe.run()


def test_demo_runs_every_stage(demo_result) -> None:
    pipe, r = demo_result
    # After registration the ratios are measured again from the registered pixels (the
    # overlap histograms are the other refinement, run only when chosen).
    assert r.stages_run == (
        "histograms",
        "response",
        "ratios",
        "registration",
        "overlap_ratios",
        "merge",
        "preview",
    )
    assert r.response is None and r.lut is None  # RAW: linear
    assert r.radiance.shape == (432, 648, 3) and r.radiance.dtype == np.float32
    assert r.preview is not None and r.preview.image.dtype == np.uint8
    assert r.registration is not None and r.registration.reference == 2
    truth = json.loads((DEMO / "truth.json").read_text())
    from hdrcore.registration import corner_error

    for k, p in enumerate(r.registration.pairs):
        err = corner_error(p.matrix, np.array(truth["pairs"][k]["matrix"]), r.bracket.shape)
        assert float(np.max(err)) < 0.2, (k, err)
    # Merge times are anchored to the EXIF seconds.
    assert r.exposure_times[0] == pytest.approx(1 / 256, rel=0.05)


def test_rerun_reuses_cached_stages(demo_result) -> None:
    pipe, first = demo_result
    r = pipe.run(first.params.replace(tonemap_exposure=1.5))
    assert r.stages_run == ("preview",)
    assert r.timings["histograms"] == 0.0
    r2 = pipe.run(r.params.replace(noise_floor=first.noise_floor + 10))
    assert r2.stages_run[0] == "ratios" and "histograms" not in r2.stages_run
    fast = pipe.run(r2.params.replace(saturation=first.saturation - 50), until="ratios")
    assert fast.stages_run == ("ratios",)
    assert fast.exposures is fast.exposures_histogram
    assert fast.registration is None and fast.merge is None and fast.preview is None
    assert fast.saturation == pytest.approx(first.saturation - 50)


def test_report_is_json_with_command_field_names(demo_result) -> None:
    _, r = demo_result
    rep = json.loads(json.dumps(r.to_report()))
    pair = rep["ratios"]["pairs"][0]
    for key in (
        "dark",
        "bright",
        "ratio",
        "initial_ratio",
        "iterations",
        "equations",
        "inliers",
        "exif_ratio",
        "mismatch_stops",
        "std_error",
        "status",
        "message",
    ):
        assert key in pair
    reg = rep["registration"]
    # the same document as `hdrcore align --json` (one serialiser)
    assert set(reg) == {
        "reference",
        "model",
        "method",
        "ratios_source",
        "pairs",
        "to_reference",
        "to_reference_homography",
        "local",
    }
    assert set(reg["pairs"][0]) == set(r.registration.pairs[0].to_json())
    # local refinement: null when it did not run (no pair left misaligned), else its frames
    assert reg["local"] is None or {"tile", "frames", "summary"} <= set(reg["local"])
    for key in (
        "dark",
        "bright",
        "matrix",
        "homography",
        "dx",
        "dy",
        "angle_deg",
        "scale",
        "ratio",
        "model",
        "method",
        "cost_before",
        "cost_after",
        "overlap",
        "iterations",
        "seconds",
        "status",
        "message",
        "residual",
        "ratio_found",
    ):
        assert key in reg["pairs"][0]
    assert rep["timings"]["total"] > 0
    assert rep["verdicts"] and all("message" in v for v in rep["verdicts"])


def test_align_none_and_bad_parameters(demo_result) -> None:
    pipe, r = demo_result
    r0 = pipe.run(r.params.replace(align="none"))
    assert r0.registration is None and r0.registration_json() is None
    with pytest.raises(ParameterError, match="saturation level out of range"):
        pipe.run(r.params.replace(saturation=10**6))
    with pytest.raises(ParameterError, match="noise floor out of range"):
        pipe.run(r.params.replace(noise_floor=r.saturation + 1))
    with pytest.raises(ParameterError, match="unknown alignment"):
        pipe.run(r.params.replace(align="affine-ish"))
    with pytest.raises(ParameterError, match="reference frame out of range"):
        pipe.run(r.params.replace(reference=9))
    with pytest.raises(ParameterError, match="unknown tonemap method"):
        pipe.run(r.params.replace(tonemap="nope"))


def test_handheld_8bit_png_with_recovered_response(handheld_png: Path) -> None:
    b = load_bracket([handheld_png])
    r = Pipeline(b, PipelineParams(preview_max_side=100)).run()
    assert r.response is not None and r.response.is_monotone
    assert r.lut is not None and r.lut.shape == (3, 256)
    assert r.registration is not None and r.registration.ok
    assert r.preview.image.shape[1] <= 100
    assert np.all(np.isfinite(r.radiance))


def test_progress_is_reported(demo_result) -> None:
    seen = []
    b = demo_result[0].bracket
    Pipeline(b, progress=lambda s, f, m: seen.append((s, f))).run(PipelineParams(align="shift"))
    stages = {s for s, _ in seen}
    assert {"histograms", "ratios", "registration", "merge", "preview"} <= stages


def test_no_exposure_times_recovers_response_from_measured_ratios(tmp_path: Path) -> None:
    sim = simulate_bracket(
        scene="patches",
        shape=(96, 144),
        exposure_times=(1.0, 4.0, 16.0),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=2,
    )
    write_bracket(tmp_path, sim, fmt="png")
    (tmp_path / "exposure_times.txt").unlink()
    from hdrcore.io import load_frame

    frames = sorted(tmp_path.glob("*.png"))
    # Strip EXIF by re-encoding the pixels only.
    from hdrcore.io import write_png

    for f in frames:
        lv = load_frame(f).levels.astype(np.uint8)
        f.unlink()
        write_png(f, lv)
    b = load_bracket(frames)
    assert not b.has_exposure_times
    r = Pipeline(b, PipelineParams(align="none", preview_max_side=64)).run()
    assert r.response is not None and r.response.is_monotone
    assert r.exposures.ratios == pytest.approx((4.0, 4.0), rel=0.1)


def test_progress_callback_can_cancel(demo_result) -> None:
    from hdrcore.pipeline import Cancelled

    b = demo_result[0].bracket

    def cancel_at_registration(stage: str, fraction: float, message: str) -> None:
        if stage == "registration":
            raise Cancelled()

    pipe = Pipeline(b, progress=cancel_at_registration)
    with pytest.raises(Cancelled):
        pipe.run()
    # The stages before it are cached: a new run starts at the registration.
    pipe.progress = None
    r = pipe.run()
    assert r.stages_run[0] == "registration"


def test_ratio_errors_over_one_percent_are_flagged(demo_result) -> None:
    _, r = demo_result
    truth = json.loads((DEMO / "truth.json").read_text())["ratios"]
    assert r.exposures is not r.exposures_histogram  # re-measured after registration
    checked = 0
    for res in (r.exposures_histogram, r.exposures):
        for p, t in zip(res.pairs, truth, strict=True):
            if abs(p.ratio / t - 1) > 0.01:
                assert p.status != "ok", (p.dark, p.ratio, t)
                checked += 1
    assert checked > 0  # the demo's motion does bias some whole-frame ratio by over 1 %


def test_binned_registration_scales_back_to_full_resolution(demo_result) -> None:
    from hdrcore.registration import corner_error

    b = demo_result[0].bracket
    truth = json.loads((DEMO / "truth.json").read_text())
    r = Pipeline(b, PipelineParams(registration_max_pixels=100_000)).run(until="registration")
    assert r.registration is not None
    for k, p in enumerate(r.registration.pairs):
        assert p.shape == b.shape and "binned 2x2" in p.message
        err = corner_error(p.matrix, np.array(truth["pairs"][k]["matrix"]), b.shape)
        assert float(np.max(err)) < 0.2, (k, err)
    assert len(r.registration.to_reference) == len(b)


def test_bin_channel_matches_block_mean() -> None:
    from hdrcore.resample import bin_channel

    x = np.random.default_rng(0).integers(0, 4096, (9, 13, 3), dtype=np.uint16)
    out = bin_channel(x, 1, 2)
    expected = x[:8, :12, 1].reshape(4, 2, 6, 2).mean(axis=(1, 3))
    np.testing.assert_allclose(out, expected, rtol=1e-6)


def test_registered_pixel_ratios_are_accurate_and_used_for_the_merge(demo_result) -> None:
    _, r = demo_result
    truth = json.loads((DEMO / "truth.json").read_text())["ratios"]
    assert r.exposures.method == "registered pixels"
    for p, t in zip(r.exposures.pairs, truth, strict=True):
        # RAW: measured on the CFA sites (half-size planes of a 432x648 frame).
        assert p.ok and abs(p.ratio / t - 1) < 0.003, (p.dark, p.ratio, p.message)
    assert r.times_source == "estimated"
    rel = np.array(r.exposure_times) / r.exposure_times[0]
    np.testing.assert_allclose(rel, np.cumprod([1.0, *truth]), rtol=0.004)


def test_histogram_refinement_still_runs_by_name(demo_result) -> None:
    b = demo_result[0].bracket
    r = Pipeline(b, PipelineParams(refine_ratios="histograms")).run(until="overlap_ratios")
    assert "overlap_histograms" in r.stages_run
    assert all(p.overlap_restricted for p in r.exposures.pairs)
    assert r.exposures.method != "registered pixels"
    off = Pipeline(b, PipelineParams(refine_ratios="none")).run(until="overlap_ratios")
    assert off.exposures is off.exposures_histogram
    with pytest.raises(ParameterError):
        Pipeline(b, PipelineParams(refine_ratios="pixel")).run(until="ratios")


def test_reuse_buffers_writes_the_next_merge_into_the_previous_arrays(demo_result) -> None:
    b = demo_result[0].bracket
    fresh = Pipeline(b).run(until="merge")
    pipe = Pipeline(b, reuse_buffers=True)
    first = pipe.run(until="merge")
    first_radiance = first.radiance
    pipe.clear_cache()
    second = pipe.run(until="merge")
    assert np.shares_memory(second.merge.radiance, first.merge.radiance)
    np.testing.assert_array_equal(second.radiance, fresh.radiance)
    # A parameter change that makes the merge stale reuses the cached merge's arrays.
    third = pipe.run(second.params.replace(noise_floor=second.noise_floor + 20), until="merge")
    assert np.shares_memory(third.merge.shares, first.merge.shares)
    other = Pipeline(b).run(third.params, until="merge")
    np.testing.assert_array_equal(third.radiance, other.radiance)
    assert first_radiance is first.radiance  # the old result object now holds the new values
    # Without the option every merge has arrays of its own.
    plain = Pipeline(b)
    a = plain.run(until="merge")
    plain.clear_cache()
    assert not np.shares_memory(plain.run(until="merge").merge.radiance, a.merge.radiance)


def test_release_hands_a_result_no_longer_shown_to_the_next_merge(demo_result) -> None:
    """A viewer shows the latest result while the next one is computed, and releases the one
    before it: the next merge writes into the released arrays, never into the shown or the
    cached result's, and gives the same values as a fresh merge."""
    b = demo_result[0].bracket
    pipe = Pipeline(b)
    shown = pipe.run(until="merge")
    pipe.release(shown)  # the cached merge: ignored
    p2 = shown.params.replace(noise_floor=shown.noise_floor + 20)
    second = pipe.run(p2, until="merge")
    assert not np.shares_memory(second.merge.radiance, shown.merge.radiance)
    pipe.release(shown)  # no longer shown: second is
    assert pipe.run(p2, until="merge").merge is second.merge  # a cache hit keeps the release
    p3 = shown.params.replace(noise_floor=shown.noise_floor + 40)
    third = pipe.run(p3, until="merge")
    assert np.shares_memory(third.merge.radiance, shown.merge.radiance)
    assert np.shares_memory(third.merge.shares, shown.merge.shares)
    assert not np.shares_memory(third.merge.radiance, second.merge.radiance)
    np.testing.assert_array_equal(third.radiance, Pipeline(b).run(p3, until="merge").radiance)
    # a released result is used once; a result of another size is ignored
    fourth = pipe.run(shown.params, until="merge")
    assert not np.shares_memory(fourth.merge.radiance, third.merge.radiance)
    from hdrcore.merge import merge

    other = merge(
        [f.levels[:16, :24] for f in b.frames], fourth.exposure_times, max_level=b.max_level
    )
    pipe.release(other)
    fifth = pipe.run(p2, until="merge")
    assert not np.shares_memory(fifth.merge.radiance, other.radiance)
    np.testing.assert_array_equal(fifth.radiance, second.radiance)


def test_deghost_parameter_reruns_only_the_merge(demo_result) -> None:
    pipe = Pipeline(demo_result[0].bracket)
    r = pipe.run(until="merge")
    assert r.merge.deghosted is None
    d = pipe.run(r.params.replace(deghost=True), until="merge")
    assert d.stages_run == ("merge",)
    assert d.merge.deghosted is not None and d.merge.deghosted.shape == r.merge.shape
    assert not (d.merge.deghosted & ~_grown(r.merge.ghost)).any()
    back = pipe.run(r.params, until="merge")
    assert back.merge.deghosted is None


def _grown(mask: np.ndarray) -> np.ndarray:
    from scipy import ndimage

    return ndimage.binary_dilation(mask, iterations=2)

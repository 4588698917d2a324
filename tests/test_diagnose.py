"""Verdict helpers (issue 17, point 3): which pairs a merge took from EXIF is read from the
pipeline's ``times_source`` by whole pair names, so pair 1-2 is not found inside 11-12."""

from __future__ import annotations

from hdrcore.diagnose import exif_pairs


def test_exif_pairs_are_whole_names() -> None:
    src = "estimated; EXIF for pairs 11-12, 3-4"
    assert exif_pairs(src) == {"11-12", "3-4"}
    assert "1-2" not in exif_pairs(src)  # the substring test found it inside 11-12
    assert exif_pairs("estimated") == set()
    assert exif_pairs("exif") == set()


def test_corner_shift_reads_the_pair_motion_at_the_corners() -> None:
    from types import SimpleNamespace

    import numpy as np

    from hdrcore.diagnose import _corner_shift_px

    shift = np.array([[1.0, 0.0, 3.0], [0.0, 1.0, -4.0], [0.0, 0.0, 1.0]])
    rp = SimpleNamespace(usable=True, shape=(100, 200), homography=shift)
    assert _corner_shift_px(rp) == 5.0
    # a rotation about the origin moves the far corner most
    a = np.deg2rad(0.5)
    rot = np.array([[np.cos(a), -np.sin(a), 0.0], [np.sin(a), np.cos(a), 0.0], [0, 0, 1.0]])
    rp = SimpleNamespace(usable=True, shape=(100, 200), homography=rot)
    assert abs(_corner_shift_px(rp) - np.hypot(199, 99) * 2 * np.sin(a / 2)) < 1e-9
    assert np.isnan(_corner_shift_px(SimpleNamespace(usable=False, shape=(1, 1), homography=rot)))


def test_a_pair_that_barely_moved_is_not_said_to_have_moved(memorial_dir) -> None:
    """The memorial's film scans: pair 3-4 moves about a pixel at the corners and its
    whole-frame and registered-pixel ratios differ by 18 %; that is not blamed on hand-held
    motion. Each pair's verdict follows its own motion."""
    from hdrcore.diagnose import MOTION_BIAS_PX, _corner_shift_px, diagnose
    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams

    r = Pipeline(load_bracket([memorial_dir])).run(PipelineParams(), until="merge")
    shifts = [_corner_shift_px(p) for p in r.registration.pairs]
    verdicts = diagnose(r)
    codes = ("motion-biased-ratio", "ratio-estimates-differ")
    said = {v.frames[0]: v.code for v in verdicts if v.code in codes}
    assert said.get(3) == "ratio-estimates-differ" and shifts[3] <= MOTION_BIAS_PX
    for k, code in said.items():
        if code == "motion-biased-ratio":
            assert shifts[k] > MOTION_BIAS_PX
        else:
            assert code == "ratio-estimates-differ" and shifts[k] <= MOTION_BIAS_PX


def test_non_linear_frames_without_times_warn_of_the_ratio_response_trade_off(
    tmp_path,
) -> None:
    """Without exposure times a JPEG/PNG bracket's ratios and response trade off (the real
    frobisher without EXIF: 13.1 and 13.2 for 8): a warning says so; with a times file it is
    not given."""
    from PIL import Image

    from hdrcore.io import load_bracket
    from hdrcore.pipeline import Pipeline, PipelineParams
    from hdrcore.synthetic import simulate_bracket, write_bracket

    sim = simulate_bracket(
        scene="window",
        shape=(96, 144),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        seed=3,
    )
    write_bracket(tmp_path, sim, fmt="png")
    files = sorted(tmp_path.glob("*.png"))
    for f in files:  # the simulator writes the times into the PNGs: saved again without them
        Image.open(f).copy().save(f, exif=b"")
    params = PipelineParams(align="none")
    bare = load_bracket(files)
    assert "no-exposure-times" in bare.warning_codes()
    res = Pipeline(bare).run(params, until="ratios")
    (v,) = [v for v in res.verdicts if v.code == "ratios-response-ambiguous"]
    assert v.severity == "warning" and "--times" in v.message
    # a response given (a calibrated curve) leaves nothing to trade
    given = Pipeline(bare).run(params.replace(response=res.response), until="ratios")
    assert not any(v.code == "ratios-response-ambiguous" for v in given.verdicts)
    times = {f.name: t for f, t in zip(files, (1 / 64, 1 / 16, 1 / 4), strict=True)}
    timed = Pipeline(load_bracket(files, exposure_times=times)).run(params, until="ratios")
    assert not any(v.code == "ratios-response-ambiguous" for v in timed.verdicts)

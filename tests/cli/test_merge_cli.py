"""``hdrcore merge``: outputs, report fields, refusals, bad input, exit codes."""

from __future__ import annotations

import json
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from hdrcore.cli import main
from hdrcore.io import read_exr
from hdrcore.synthetic import simulate_bracket, write_bracket

ROOT = Path(__file__).resolve().parents[2]
DEMO = ROOT / "assets" / "demo"


@pytest.fixture(scope="module")
def png_bracket(tmp_path_factory: pytest.TempPathFactory) -> Path:
    sim = simulate_bracket(
        scene="patches",
        shape=(96, 144),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        seed=5,
    )
    out = tmp_path_factory.mktemp("png")
    write_bracket(out, sim, fmt="png")
    return out


def test_merge_demo_writes_exr_preview_and_report(tmp_path: Path, capsys) -> None:
    exr, png, rep = tmp_path / "o.exr", tmp_path / "o.png", tmp_path / "r.json"
    rc = main(
        ["merge", str(DEMO), "-o", str(exr), "--preview", str(png), "--report", str(rep), "--quiet"]
    )
    assert rc == 0, capsys.readouterr().err  # no error verdict on the demo
    rgb, attrs = read_exr(exr)
    assert rgb.shape == (432, 648, 3) and np.all(np.isfinite(rgb)) and rgb.max() > 0
    assert len(attrs["exposureTimes"]) == 5
    assert len(attrs["hdrviewTransforms"]) == 5
    assert attrs["hdrviewSources"][0] == "frame00.dng"
    report = json.loads(rep.read_text())
    assert set(report["ratios"]) == {"frames", "pairs"}
    assert report["registration"]["reference"] == 2
    assert len(report["registration"]["to_reference"]) == 5
    for stage in ("histograms", "ratios", "registration", "merge", "preview", "decode", "write"):
        assert stage in report["timings"]
    assert report["merge"]["status"] in ("ok", "warning")
    assert png.stat().st_size > 1000


def test_deghost_and_exr_compression_options(tmp_path: Path, capsys) -> None:
    exr, rep = tmp_path / "d.exr", tmp_path / "d.json"
    rc = main(
        [
            "merge",
            str(DEMO),
            "-o",
            str(exr),
            "--report",
            str(rep),
            "--deghost",
            "--exr-compression",
            "zip",
            "--quiet",
        ]
    )
    assert rc == 0, capsys.readouterr().err
    report = json.loads(rep.read_text())
    assert report["parameters"]["deghost"] is True
    assert 0.0 <= report["merge"]["deghosted_fraction"] <= 1.0
    plain = tmp_path / "p.json"
    main(["merge", str(DEMO), "-o", str(tmp_path / "p.exr"), "--report", str(plain), "--quiet"])
    assert json.loads(plain.read_text())["merge"]["deghosted_fraction"] is None
    assert read_exr(exr)[0].shape == (432, 648, 3)


def test_existing_output_refused_and_kept(tmp_path: Path, capsys) -> None:
    exr = tmp_path / "o.exr"
    exr.write_bytes(b"keep me")
    rc = main(["merge", str(DEMO), "-o", str(exr), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 2 and "output exists; use --force" in err and "o.exr" in err
    assert exr.read_bytes() == b"keep me"


def test_outputs_are_refused_before_any_decoding(tmp_path: Path, capsys, monkeypatch) -> None:
    """An existing output, an output over an input and a missing directory are refused before
    the frames are decoded (seconds at 24 MP)."""
    import hdrcore.cli.merge as merge_cli

    def no_decoding(*_args, **_kwargs):
        raise AssertionError("decoded before the outputs were checked")

    monkeypatch.setattr(merge_cli, "load_bracket_from_args", no_decoding)
    exr = tmp_path / "o.exr"
    exr.write_bytes(b"keep me")
    assert main(["merge", str(DEMO), "-o", str(exr), "--quiet"]) == 2
    assert "output exists" in capsys.readouterr().err and exr.read_bytes() == b"keep me"
    frame = sorted(DEMO.glob("*.dng"))[0]
    assert (
        main(
            ["merge", str(DEMO), "-o", str(tmp_path / "x.exr"), "--preview", str(frame), "--quiet"]
        )
        == 2
    )
    assert "overwrite an input" in capsys.readouterr().err
    assert main(["merge", str(DEMO), "-o", str(tmp_path / "nope" / "x.exr"), "--quiet"]) == 2
    assert "directory does not exist" in capsys.readouterr().err


def test_refuses_overwriting_an_input(png_bracket: Path, capsys) -> None:
    frame = sorted(png_bracket.glob("*.png"))[0]
    before = frame.read_bytes()
    rc = main(
        [
            "merge",
            str(png_bracket),
            "-o",
            str(png_bracket / "x.exr"),
            "--preview",
            str(frame),
            "--force",
            "--quiet",
        ]
    )
    err = capsys.readouterr().err
    assert rc == 2 and "refusing to overwrite an input file" in err
    assert frame.read_bytes() == before
    assert not (png_bracket / "x.exr").exists()


def test_unreadable_frame_is_a_one_line_error(tmp_path: Path, png_bracket: Path, capsys) -> None:
    frames = sorted(png_bracket.glob("*.png"))
    bad = tmp_path / "broken.png"
    bad.write_bytes(frames[0].read_bytes()[:300])
    rc = main(["merge", str(frames[1]), str(bad), "-o", str(tmp_path / "o.exr"), "--quiet"])
    err = capsys.readouterr().err.strip().splitlines()
    assert rc == 2
    assert len(err) == 1 and "broken.png" in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "o.exr").exists()


def test_non_exr_output_name(tmp_path: Path, png_bracket: Path, capsys) -> None:
    rc = main(["merge", str(png_bracket), "-o", str(tmp_path / "o.tif"), "--quiet"])
    assert rc == 2 and "must be an OpenEXR file" in capsys.readouterr().err


def test_png_bracket_merges_with_json_report(tmp_path: Path, png_bracket: Path, capsys) -> None:
    rc = main(
        [
            "merge",
            str(png_bracket),
            "-o",
            str(tmp_path / "o.exr"),
            "--align",
            "none",
            "--json",
            "--quiet",
        ]
    )
    out = capsys.readouterr().out
    report = json.loads(out)
    assert rc == 0, capsys.readouterr().err
    assert not [v for v in report["verdicts"] if v["severity"] == "error"]
    assert report["registration"] is None
    assert report["response"]["method"]
    assert len(report["ratios"]["pairs"]) == 2


def test_crop_common_writes_only_what_every_frame_covers(tmp_path: Path, capsys) -> None:
    """The demo is hand-held: --crop common writes the EXR and the preview cropped to a
    rectangle every frame covers (each frame's motion maps its corners inside that frame) and
    says so in the report and the EXR."""
    from hdrcore.geometry import apply, homogeneous, invert

    exr, png, rep = tmp_path / "c.exr", tmp_path / "c.png", tmp_path / "c.json"
    rc = main(
        ["merge", str(DEMO), "-o", str(exr), "--preview", str(png), "--report", str(rep)]
        + ["--crop", "common", "--quiet"]
    )
    assert rc == 0, capsys.readouterr().err
    report = json.loads(rep.read_text())
    x0, y0, x1, y1 = report["crop"]["rectangle"]
    h, w = 432, 648
    assert 0 <= x0 < x1 <= w and 0 <= y0 < y1 <= h
    assert (x1 - x0) * (y1 - y0) < h * w  # the frames moved: something is cut
    assert report["crop"]["kept"] == pytest.approx((x1 - x0) * (y1 - y0) / (h * w), abs=1e-4)
    rgb, attrs = read_exr(exr)
    assert rgb.shape == (y1 - y0, x1 - x0, 3)
    assert attrs["hdrview"]["crop"] == [x0, y0, x1, y1]
    xs = np.array([x0, x1 - 1, x0, x1 - 1], float)
    ys = np.array([y0, y0, y1 - 1, y1 - 1], float)
    for m in report["registration"]["to_reference"]:
        sx, sy = apply(invert(homogeneous(np.asarray(m, float))), xs, ys)
        assert np.all((sx >= 0) & (sx <= w - 1) & (sy >= 0) & (sy <= h - 1))
    # and it is the largest such rectangle to within a pixel per side: one pixel more on
    # some side leaves some frame
    grown = [(x0 - 1, y0, x1, y1), (x0, y0 - 1, x1, y1), (x0, y0, x1 + 1, y1), (x0, y0, x1, y1 + 1)]
    for gx0, gy0, gx1, gy1 in grown:
        if gx0 < 0 or gy0 < 0 or gx1 > w or gy1 > h:
            continue
        yy, xx = np.mgrid[gy0:gy1, gx0:gx1].astype(float)
        inside = np.ones(xx.shape, bool)
        for m in report["registration"]["to_reference"]:
            sx, sy = apply(invert(homogeneous(np.asarray(m, float))), xx, yy)
            inside &= (sx >= 2) & (sx <= w - 3) & (sy >= 2) & (sy <= h - 3)
        assert not inside.all()
    from PIL import Image

    full = tmp_path / "f.png"
    assert (
        main(
            ["merge", str(DEMO), "-o", str(tmp_path / "f.exr"), "--preview", str(full)]
            + ["--quiet"]
        )
        == 0
    )
    cw, ch = Image.open(png).size
    fw, fh = Image.open(full).size
    assert cw < fw or ch < fh


def test_crop_with_dng_is_refused_before_any_work(tmp_path: Path, capsys) -> None:
    rc = main(
        ["merge", str(DEMO), "-o", str(tmp_path / "o.exr"), "--dng", str(tmp_path / "o.dng")]
        + ["--crop", "common", "--quiet"]
    )
    err = capsys.readouterr().err
    assert rc != 0 and "--crop" in err and "o.dng" in err
    assert not (tmp_path / "o.exr").exists() and not (tmp_path / "o.dng").exists()


def _merge_outputs(tmp_path: Path, name: str, *extra: str) -> tuple[bytes, bytes, object]:
    exr, png, rep = (tmp_path / f"{name}.{s}" for s in ("exr", "png", "json"))
    rc = main(
        ["merge", str(DEMO), "-o", str(exr), "--preview", str(png), "--report", str(rep)]
        + ["--quiet", *extra]
    )
    assert rc == 0
    report = json.loads(rep.read_text())
    report.pop("outputs")
    return exr.read_bytes(), png.read_bytes(), _without_timings(report)


def _without_timings(obj: object) -> object:
    if isinstance(obj, dict):
        return {k: _without_timings(v) for k, v in obj.items() if k not in ("timings", "seconds")}
    if isinstance(obj, list):
        return [_without_timings(v) for v in obj]
    return obj


def test_memory_savings_leave_every_output_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """The command lets go of the RAW mosaics when the merge starts and makes the EXR's half
    floats in the radiance's own memory: the EXR, the preview and the report are those of a
    run that keeps both (the demo: a hand-held DNG bracket whose noise is measured on the
    mosaics and whose ratios are refined on registered CFA sites)."""
    import hdrcore.cli.merge as merge_cli

    released: list[int] = []
    overwrite: list[bool] = []
    release, write = merge_cli._release_mosaics, merge_cli.write_result

    def counting_release(bracket):
        released.append(release(bracket))
        assert all(f.cfa is None for f in bracket.frames)
        return released[-1]

    def recording_write(*args, **kwargs):
        overwrite.append(kwargs["overwrite_radiance"])
        return write(*args, **kwargs)

    monkeypatch.setattr(merge_cli, "_release_mosaics", counting_release)
    monkeypatch.setattr(merge_cli, "write_result", recording_write)
    saving = _merge_outputs(tmp_path, "saving")
    assert len(released) == 1 and released[0] == 5 * 432 * 648 * 2  # five 16-bit mosaics
    assert overwrite == [True]

    def no_overwrite(*args, **kwargs):
        return write(*args, **{**kwargs, "overwrite_radiance": False})

    monkeypatch.setattr(merge_cli, "_release_mosaics", lambda bracket: 0)
    monkeypatch.setattr(merge_cli, "write_result", no_overwrite)
    keeping = _merge_outputs(tmp_path, "keeping")
    assert saving[0] == keeping[0]
    assert saving[1] == keeping[1]
    assert saving[2] == keeping[2]


def test_mosaics_and_radiance_kept_for_the_dng(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """With --dng the mosaics (the CFA layout merges them) and the radiance (the linear layout
    writes it) outlive the EXR: neither is let go."""
    import hdrcore.cli.merge as merge_cli

    calls: list[object] = []
    write = merge_cli.write_result

    def recording_write(*args, **kwargs):
        calls.append(kwargs["overwrite_radiance"])
        return write(*args, **kwargs)

    monkeypatch.setattr(merge_cli, "_release_mosaics", lambda bracket: calls.append("released"))
    monkeypatch.setattr(merge_cli, "write_result", recording_write)
    rep = tmp_path / "r.json"
    rc = main(
        ["merge", str(DEMO), "-o", str(tmp_path / "o.exr"), "--dng", str(tmp_path / "o.dng")]
        + ["--report", str(rep), "--quiet"]
    )
    assert rc == 0
    assert calls == [False]
    assert json.loads(rep.read_text())["outputs"]["dng"] == str(tmp_path / "o.dng")


def test_the_merge_keeps_no_weight_maps_and_every_output_is_as_it_was(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    """``hdrcore merge`` runs the pipeline with ``weight_maps=False`` (issue 18: the shares,
    the weight sum and the clip count of a linear bracket's merge are not kept, the shares'
    summary is counted in the kernel) and gives the heap's free pages back when the ghost
    test starts: the EXR, the preview and the report (its provenance included) are those of
    a run that keeps the maps and trims nothing (the demo: a hand-held DNG bracket)."""
    import hdrcore.cli.merge as merge_cli
    from hdrcore.pipeline import Pipeline

    merges: list[object] = []

    def pipeline_with(weight_maps: bool):
        def make(*args, **kwargs):
            assert kwargs.get("weight_maps") is False  # the command asks for no maps
            pipe = Pipeline(*args, **{**kwargs, "weight_maps": weight_maps})
            run = pipe.run

            def recording_run(*a, **k):
                res = run(*a, **k)
                merges.append(res.merge)
                return res

            pipe.run = recording_run  # type: ignore[method-assign]
            return pipe

        return make

    trims: list[bool] = []
    trim = merge_cli._trim_heap
    monkeypatch.setattr(merge_cli, "_trim_heap", lambda: trims.append(trim()))
    monkeypatch.setattr(merge_cli, "Pipeline", pipeline_with(False))
    lean = _merge_outputs(tmp_path, "lean")
    assert len(trims) == 1  # the heap's free pages given back once, at the ghost test
    monkeypatch.setattr(merge_cli, "_trim_heap", lambda: False)
    monkeypatch.setattr(merge_cli, "Pipeline", pipeline_with(True))
    kept = _merge_outputs(tmp_path, "kept")
    assert merges[0].share_maps is None and merges[0].weight_sum_map is None
    assert merges[0].clip_count_map is None
    assert merges[1].share_maps is not None and merges[1].weight_sum_map is not None
    assert lean[0] == kept[0]
    assert lean[1] == kept[1]
    assert lean[2] == kept[2]
    assert lean[2]["merge"]["provenance"]["mean_share"][0] > 0


def test_a_pair_that_cannot_be_registered_exits_1(tmp_path: Path, capsys) -> None:
    """The help's contract: "1 merged, but a stage failed (e.g. a pair could not be
    registered)". A hand-held bracket (frame 1 moved) whose last frame is its own pixels
    shuffled (the same histograms: the ratios are measured; nothing to register) is merged,
    exits 1 and says so; the report's status is stage-failed."""
    sim = simulate_bracket(
        scene="window",
        shape=(240, 360),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        motion=[(0.0, 0.0, 0.0), (4.0, -3.0, 0.0), (0.0, 0.0, 0.0)],
        seed=7,
    )
    last = sim.frames[2].reshape(-1, 3).copy()
    np.random.default_rng(1).shuffle(last)
    frames = [*sim.frames[:2], last.reshape(sim.frames[2].shape)]
    write_bracket(tmp_path / "in", replace(sim, frames=frames), fmt="png")
    exr, rep = tmp_path / "o.exr", tmp_path / "r.json"
    rc = main(["merge", str(tmp_path / "in"), "-o", str(exr), "--report", str(rep), "--quiet"])
    err = capsys.readouterr().err
    assert rc == 1, err
    assert "merged, but a stage failed" in err and "registration-failed" in err
    report = json.loads(rep.read_text())
    assert report["status"] == "stage-failed"
    assert [p["status"] for p in report["registration"]["pairs"]][1] != "ok"
    assert any(v["code"] == "registration-failed" for v in report["verdicts"])
    assert exr.exists()

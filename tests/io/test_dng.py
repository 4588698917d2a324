"""Float DNG output (hdrcore.io.dng, ``hdrcore merge --dng``): values read back exactly by our
reader and by rawpy/LibRaw to its 14-bit conversion, tags checked by exiftool, orientation and
colour carried, darktable renders it like our preview."""

from __future__ import annotations

import json
import shutil
import subprocess
from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest
import rawpy

from hdrcore.cli import main
from hdrcore.errors import ParameterError
from hdrcore.io import load_bracket
from hdrcore.io.dng import DngMetadata, read_float_dng, write_float_dng
from hdrcore.merge.colour import camera_to_working_matrix
from hdrcore.synthetic import simulate_bracket, write_bracket

# A camera LibRaw has no table for, so rawpy reports the file's ColorMatrix1.
META = DngMetadata(
    make="hdrcore-test",
    model="sensor",
    color_matrix=((0.9, -0.2, 0.1), (-0.3, 1.2, 0.1), (0.0, 0.1, 0.8)),
    white_balance=(2.0, 1.0, 1.5),
    exposure_time=Fraction(1, 125),
    f_number=Fraction(8),
    iso=200,
    provenance={"exposureRatios": [4.0, 4.0], "reference": 1},
)
EXIFTOOL = shutil.which("exiftool") or (
    "/usr/bin/exiftool" if Path("/usr/bin/exiftool").exists() else None
)
DARKTABLE = shutil.which("darktable-cli")


def _image(h: int = 40, w: int = 60, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    return rng.uniform(0.001, 5.0, (h, w, 3)).astype(np.float32)


def _scale(dng) -> float:
    xmp = dng.tags[700].decode()
    return float(xmp.split("<hdrcore:scale>")[1].split("<")[0])


@pytest.mark.parametrize("bits", [16, 32])
def test_linear_round_trip_exact_and_through_rawpy(tmp_path: Path, bits: int) -> None:
    img = _image()
    p = write_float_dng(tmp_path / "a.dng", img, META, bits=bits)
    back = read_float_dng(p)
    assert back.kind == "linear" and back.image.shape == img.shape
    scale = _scale(back)
    assert scale == pytest.approx(1.0 / img.max(), rel=1e-7)
    tol = 1e-3 if bits == 16 else 1e-7  # half: 11-bit significand
    np.testing.assert_allclose(back.image, img * scale, rtol=tol, atol=1e-7)
    # BaselineExposure: log2 of the brightest value (units of the reference white).
    assert float(back.tags[50730][0]) == pytest.approx(np.log2(img.max()), abs=1e-4)
    with rawpy.imread(str(p)) as raw:
        # LibRaw turns float samples into integers, the largest at its white level 16383.
        assert raw.white_level == 16383
        got = raw.raw_image.astype(np.float64) / raw.white_level
        assert np.abs(got - back.image).max() <= 1.0 / 16383
        assert list(raw.camera_whitebalance[:3]) == pytest.approx([2.0, 1.0, 1.5], rel=1e-6)
        # LibRaw keeps a DNG's ColorMatrix1 to itself and reports the camera -> sRGB matrix
        # it derives from it (dcraw's rgb_cam), which ours derives the same way.
        want = camera_to_working_matrix(np.asarray(META.color_matrix), None, "sRGB")
        np.testing.assert_allclose(raw.color_matrix[:, :3], want, atol=2e-3)


def test_cfa_round_trip(tmp_path: Path) -> None:
    rng = np.random.default_rng(1)
    m = rng.uniform(0.0, 3.0, (32, 48)).astype(np.float32)
    p = write_float_dng(tmp_path / "c.dng", m, META, kind="cfa", cfa_pattern=[[1, 0], [2, 1]])
    back = read_float_dng(p)
    assert back.kind == "cfa"
    np.testing.assert_allclose(back.image, m * _scale(back), rtol=1e-7)
    with rawpy.imread(str(p)) as raw:
        assert raw.raw_type == rawpy.RawType.Flat
        letters = [raw.color_desc.decode()[i] for i in raw.raw_pattern.ravel()]
        assert letters == ["G", "R", "B", "G"]
        got = raw.raw_image.astype(np.float64) / raw.white_level
        assert np.abs(got - back.image).max() <= 1.0 / 16383


@pytest.mark.parametrize("orientation", [3, 6, 8])
def test_orientation_is_carried(tmp_path: Path, orientation: int) -> None:
    """The samples are stored as the sensor saw them and the tag turns them back upright:
    LibRaw's output puts a bright spot where it was in the upright image."""
    img = np.full((30, 50, 3), 0.1, np.float32)
    img[4:7, 9:12] = 1.0
    meta = DngMetadata(**{**META.__dict__, "orientation": orientation})
    p = write_float_dng(tmp_path / "o.dng", img, meta)
    with rawpy.imread(str(p)) as raw:
        up = raw.postprocess(
            gamma=(1, 1),
            no_auto_bright=True,
            output_bps=16,
            user_wb=[1, 1, 1, 1],
            output_color=rawpy.ColorSpace.raw,
        )
    assert up.shape[:2] == img.shape[:2]
    y, x = np.unravel_index(np.argmax(up.sum(axis=2)), up.shape[:2])
    assert 4 <= y <= 6 and 9 <= x <= 11


@pytest.mark.skipif(EXIFTOOL is None, reason="exiftool (libimage-exiftool-perl) not installed")
def test_tags_checked_by_exiftool(tmp_path: Path) -> None:
    p = write_float_dng(
        tmp_path / "t.dng", _image(), DngMetadata(**{**META.__dict__, "orientation": 6})
    )
    out = subprocess.run(
        [EXIFTOOL, "-j", "-n", "-a", "-G1", str(p)], capture_output=True, text=True, check=True
    )
    tags = json.loads(out.stdout)[0]
    assert tags["IFD0:DNGVersion"] == "1 4 0 0"
    assert tags["IFD0:PhotometricInterpretation"] == 34892
    assert tags["IFD0:SampleFormat"] == "3 3 3"
    assert tags["IFD0:BitsPerSample"] == "32 32 32"
    assert tags["IFD0:BlackLevel"] == 0 and tags["IFD0:WhiteLevel"] == 1
    assert tags["IFD0:Orientation"] == 6
    assert [float(v) for v in tags["IFD0:ColorMatrix1"].split()] == pytest.approx(
        np.ravel(META.color_matrix).tolist()
    )
    assert [float(v) for v in tags["IFD0:AsShotNeutral"].split()] == pytest.approx(
        [0.5, 1.0, 1 / 1.5]
    )
    assert tags["IFD0:CalibrationIlluminant1"] == 21
    assert tags["ExifIFD:ExposureTime"] == pytest.approx(1 / 125)
    assert tags["ExifIFD:FNumber"] == 8 and tags["ExifIFD:ISO"] == 200
    assert json.loads(tags["XMP-hdrcore:ExposureRatios"]) == [4.0, 4.0]
    assert "Warning" not in tags and "ExifTool:Warning" not in tags, tags.get("ExifTool:Warning")


def test_bad_inputs_are_named(tmp_path: Path) -> None:
    with pytest.raises(ParameterError, match="float image"):
        write_float_dng(tmp_path / "x.dng", np.ones((4, 4, 3), np.uint16), META)
    with pytest.raises(ParameterError, match="RGB image"):
        write_float_dng(tmp_path / "x.dng", np.ones((4, 4), np.float32), META)
    with pytest.raises(ParameterError, match="unknown DNG layout"):
        write_float_dng(tmp_path / "x.dng", _image(), META, kind="ycbcr")
    with pytest.raises(ParameterError, match="sample size"):
        write_float_dng(tmp_path / "x.dng", _image(), META, bits=24)
    with pytest.raises(ParameterError, match="no positive finite"):
        write_float_dng(tmp_path / "x.dng", np.zeros((4, 4, 3), np.float32), META)
    with pytest.raises(ParameterError, match="Bayer"):
        write_float_dng(
            tmp_path / "x.dng",
            np.ones((4, 4), np.float32),
            META,
            kind="cfa",
            cfa_pattern=[[0, 0], [1, 2]],
        )
    assert not list(tmp_path.iterdir())  # nothing left behind


@pytest.fixture(scope="module")
def merged(tmp_path_factory) -> dict[str, Path]:
    """A 12-bit simulated RAW bracket merged with --dng, --preview and a float32 EXR."""
    d = tmp_path_factory.mktemp("dngmerge")
    sim = simulate_bracket(
        scene="window",
        shape=(192, 288),
        exposure_times=(1 / 256, 1 / 64, 1 / 16),
        bits=12,
        response="linear",
        noise_sigma=1.0,
        seed=2,
        keep_linear=True,
    )
    write_bracket(d / "in", sim, "dng")
    out = {
        "dir": d / "in",
        "exr": d / "m.exr",
        "dng": d / "m.dng",
        "png": d / "m.png",
        "json": d / "m.json",
    }
    code = main(
        [
            "merge",
            str(d / "in"),
            "-o",
            str(out["exr"]),
            "--dng",
            str(out["dng"]),
            "--dng-layout",
            "linear",
            "--preview",
            str(out["png"]),
            "--report",
            str(out["json"]),
            "--float32",
            "--quiet",
        ]
    )
    assert code in (0, 1)
    return out


@pytest.fixture(scope="module")
def merged_cfa(merged: dict[str, Path]) -> dict[str, Path]:
    """The same tripod bracket with --dng-layout auto: a CFA DNG of the merged mosaic."""
    d = merged["dir"].parent
    out = {"dir": merged["dir"], "dng": d / "c.dng", "png": d / "c.png", "json": d / "c.json"}
    code = main(
        [
            "merge",
            str(merged["dir"]),
            "-o",
            str(d / "c.exr"),
            "--dng",
            str(out["dng"]),
            "--preview",
            str(out["png"]),
            "--report",
            str(out["json"]),
            "--quiet",
        ]
    )
    assert code in (0, 1)
    return out


def test_tripod_raw_bracket_gets_the_merged_mosaic(merged_cfa: dict[str, Path]) -> None:
    """auto picks the CFA layout for a tripod RAW bracket; sample / scale is the reference
    frame's black-subtracted level / max_level at its well-exposed sites, and LibRaw reads
    the mosaic with its pattern."""
    report = json.loads(merged_cfa["json"].read_text())
    assert report["outputs"]["dng_layout"] == "cfa"
    dng = read_float_dng(merged_cfa["dng"])
    assert dng.kind == "cfa"
    b = load_bracket([merged_cfa["dir"]])
    cfa = b.frames[1].cfa
    lin = (cfa.data.astype(np.float64) - 256) / b.max_level
    ok = (lin > 0.05) & (lin < 0.9)
    assert np.median(dng.image[ok] / _scale(dng) / lin[ok]) == pytest.approx(1.0, abs=2e-3)
    with rawpy.imread(str(merged_cfa["dng"])) as raw:
        letters = [raw.color_desc.decode()[i] for i in raw.raw_pattern.ravel()]
        assert letters == ["R", "G", "G", "B"]
        got = raw.raw_image.astype(np.float64) / raw.white_level
        assert np.abs(got - dng.image).max() <= 1.0 / 16383


def test_hand_held_bracket_gets_linear_and_refuses_cfa(tmp_path: Path) -> None:
    sim = simulate_bracket(
        scene="window",
        shape=(160, 240),
        exposure_times=(1 / 64, 1 / 16),
        bits=12,
        response="linear",
        noise_sigma=1.0,
        max_shift=4,
        seed=5,
        keep_linear=True,
    )
    write_bracket(tmp_path / "in", sim, "dng")
    rep = tmp_path / "r.json"
    assert main(
        [
            "merge",
            str(tmp_path / "in"),
            "-o",
            str(tmp_path / "m.exr"),
            "--dng",
            str(tmp_path / "m.dng"),
            "--report",
            str(rep),
            "--quiet",
        ]
    ) in (0, 1)
    assert json.loads(rep.read_text())["outputs"]["dng_layout"] == "linear"
    assert (
        main(
            [
                "merge",
                str(tmp_path / "in"),
                "-o",
                str(tmp_path / "n.exr"),
                "--dng",
                str(tmp_path / "n.dng"),
                "--dng-layout",
                "cfa",
                "--quiet",
            ]
        )
        == 2
    )
    assert not (tmp_path / "n.dng").exists()


def test_merge_dng_holds_the_merged_values(merged: dict[str, Path]) -> None:
    """Sample / scale is the reference frame's linear camera value where that frame is well
    exposed, and the EXR's radiance turned back to camera RGB to float precision."""
    import OpenEXR

    from hdrcore.merge.colour import colour_conversion

    dng = read_float_dng(merged["dng"])
    img = dng.image / _scale(dng)
    report = json.loads(merged["json"].read_text())
    assert report["outputs"]["dng"] == str(merged["dng"])
    b = load_bracket([merged["dir"]])
    ref = 1  # the middle frame
    lin = b.frames[ref].levels.astype(np.float64) / b.frames[ref].max_level
    ok = (lin > 0.05) & (lin < 0.9)
    ratio = img[ok] / lin[ok]
    assert np.median(ratio) == pytest.approx(1.0, abs=1e-3)
    with OpenEXR.File(str(merged["exr"])) as f:
        rgb = np.asarray(f.channels()["RGB"].pixels, np.float64)
    f0 = b.frames[0].meta
    conv = colour_conversion(np.asarray(f0.rgb_xyz_matrix), f0.camera_whitebalance, "sRGB")
    xmp = dng.tags[700].decode()
    t_ref = json.loads(xmp.split("<hdrcore:exposureTimes>")[1].split("<")[0])[ref]
    cam = rgb @ np.linalg.inv(conv.matrix).T * t_ref
    cam = np.maximum(cam, 0)
    np.testing.assert_allclose(img, cam, rtol=1e-5, atol=1e-6 * cam.max())


def test_merge_refuses_a_dng_name_without_the_extension(
    tmp_path: Path, merged: dict[str, Path]
) -> None:
    code = main(
        [
            "merge",
            str(merged["dir"]),
            "-o",
            str(tmp_path / "m.exr"),
            "--dng",
            str(tmp_path / "m.tif"),
            "--quiet",
        ]
    )
    assert code == 2
    assert not (tmp_path / "m.exr").exists()


@pytest.mark.skipif(DARKTABLE is None, reason="darktable-cli (Debian's darktable) not installed")
@pytest.mark.parametrize("layout", ["linear", "cfa"])
def test_darktable_renders_it_like_our_preview(tmp_path: Path, request, layout: str) -> None:
    """A real raw editor opens the DNG: darktable-cli's default rendering against our preview,
    per 8x8 block (tone curves differ): their log luminances correlate and the colours of the
    blocks neither clips agree."""
    from PIL import Image

    merged = request.getfixturevalue("merged" if layout == "linear" else "merged_cfa")

    jpg = tmp_path / "dt.jpg"
    proc = subprocess.run(
        [
            DARKTABLE,
            str(merged["dng"]),
            str(jpg),
            "--core",
            "--configdir",
            str(tmp_path / "conf"),
            "--library",
            ":memory:",
        ],
        capture_output=True,
        text=True,
        timeout=300,
    )
    assert jpg.exists(), proc.stderr[-500:]
    a = np.asarray(Image.open(jpg).convert("RGB"), np.float64)
    b = np.asarray(Image.open(merged["png"]).convert("RGB"), np.float64)
    assert a.shape == b.shape

    def blocks(x: np.ndarray) -> np.ndarray:
        h, w = x.shape[0] // 8 * 8, x.shape[1] // 8 * 8
        return x[:h, :w].reshape(h // 8, 8, w // 8, 8, 3).mean(axis=(1, 3))

    la = np.log(blocks(a).mean(axis=2) + 1)
    lb = np.log(blocks(b).mean(axis=2) + 1)
    assert np.corrcoef(la.ravel(), lb.ravel())[0, 1] > 0.9
    # Chromaticity where neither is clipped or black: r/(r+g+b) and b/(r+g+b) within 0.05.
    ba, bb = blocks(a), blocks(b)
    keep = (ba.max(axis=2) < 240) & (bb.max(axis=2) < 240) & (ba.sum(2) > 60) & (bb.sum(2) > 60)
    assert keep.mean() > 0.3
    ca = ba[keep] / ba[keep].sum(axis=1, keepdims=True)
    cb = bb[keep] / bb[keep].sum(axis=1, keepdims=True)
    assert np.median(np.abs(ca - cb)) < 0.05

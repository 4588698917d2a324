"""The RGB space JPEG/PNG/TIFF frames are encoded in (ICC profile, EXIF), and a bracket in
Display P3 or Adobe RGB merged into the working space's primaries instead of being taken as
sRGB (its saturated colours came out dull or shifted)."""

from __future__ import annotations

import struct
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from hdrcore.io import load_bracket
from hdrcore.io.colour_space import exif_space, icc_description, known_space
from hdrcore.io.exif import parse_exif_tags
from hdrcore.io.ldr import read_ldr
from hdrcore.merge.colour import space_to_space_matrix
from hdrcore.pipeline import Pipeline
from hdrcore.synthetic import simulate_bracket, write_bracket


def _icc(description: str, version4: bool = False) -> bytes:
    """A minimal ICC profile holding only its description tag (v2 ``desc`` or v4 ``mluc``)."""
    if version4:
        text = description.encode("utf-16-be")
        tag = b"mluc" + b"\0" * 4 + struct.pack(">II", 1, 12) + b"enUS"
        tag += struct.pack(">II", len(text), 28) + text
    else:
        text = description.encode("latin-1") + b"\0"
        tag = b"desc" + b"\0" * 4 + struct.pack(">I", len(text)) + text + b"\0" * 79
    offset = 128 + 4 + 12
    header = struct.pack(">I", offset + len(tag)) + b"\0" * 124
    return header + struct.pack(">I", 1) + struct.pack(">4sII", b"desc", offset, len(tag)) + tag


@pytest.mark.parametrize("version4", [False, True])
def test_profile_descriptions_are_read(version4: bool) -> None:
    assert icc_description(_icc("Display P3", version4)) == "Display P3"
    assert icc_description(b"\0" * 40) is None


def test_names_map_to_working_spaces() -> None:
    assert known_space("Display P3") == "Display P3"
    assert known_space("Adobe RGB (1998)") == "Adobe RGB (1998)"
    assert known_space("Compatible with Adobe RGB (1998)") == "Adobe RGB (1998)"
    assert known_space("sRGB IEC61966-2.1") == "sRGB"
    assert known_space("ProPhoto RGB") == "ProPhoto RGB"
    assert known_space("Some printer profile") is None


def test_exif_marks_adobe_rgb_without_a_profile() -> None:
    # cameras set to Adobe RGB write ColorSpace 65535 (uncalibrated) and the DCF index R03
    tags = {"EXIF ColorSpace": 65535, "Interoperability InteroperabilityIndex": "R03"}
    e = parse_exif_tags(tags)
    assert (e.colour_space, e.interop_index) == (65535, "R03")
    assert exif_space(e.colour_space, e.interop_index) == "Adobe RGB (1998)"
    assert exif_space(1, "R98") == "sRGB"
    assert exif_space(65535, None) is None


def test_a_jpeg_with_a_p3_profile_says_so(tmp_path: Path) -> None:
    p = tmp_path / "p3.jpg"
    Image.fromarray(np.full((16, 24, 3), 120, np.uint8)).save(p, icc_profile=_icc("Display P3"))
    meta = read_ldr(p).meta
    assert meta.colour_space == "Display P3"
    assert meta.colour_space_source == "ICC profile 'Display P3'"
    plain = tmp_path / "plain.png"
    Image.fromarray(np.full((16, 24, 3), 120, np.uint8)).save(plain)
    assert read_ldr(plain).meta.colour_space is None  # not stated: taken as sRGB


def test_a_p3_bracket_is_merged_into_srgb_primaries(tmp_path: Path) -> None:
    sim = simulate_bracket(
        scene="patches",
        shape=(96, 144),
        exposure_times=(1 / 64, 1 / 16, 1 / 4),
        bits=8,
        response="gamma",
        noise_sigma=0.5,
        seed=6,
    )
    plain = tmp_path / "plain"
    write_bracket(plain, sim, fmt="png")
    tagged = tmp_path / "p3"
    tagged.mkdir()
    times = {}
    for k, f in enumerate(sim.frames):
        name = f"frame{k:02d}.png"
        Image.fromarray(f.astype(np.uint8)).save(tagged / name, icc_profile=_icc("Display P3"))
        times[name] = sim.exposure_times[k]
    b_plain = load_bracket([plain], exposure_times=dict(times))
    b_p3 = load_bracket([tagged], exposure_times=dict(times))
    assert [f.meta.colour_space for f in b_p3.frames] == ["Display P3"] * 3
    r_plain = Pipeline(b_plain).run(until="merge")
    r_p3 = Pipeline(b_p3).run(until="merge")
    assert r_p3.merge is not None and r_plain.merge is not None
    rad, want = (
        r_p3.merge.radiance,
        r_plain.merge.radiance @ space_to_space_matrix("Display P3", "sRGB").T.astype(np.float32),
    )
    ok = np.isfinite(want).all(axis=-1)
    assert np.allclose(rad[ok], want[ok], rtol=1e-5, atol=1e-7)
    assert "Display P3" in r_p3.colour["conversion"] and r_p3.colour["source_space"] == "Display P3"


def test_unknown_and_mixed_spaces_are_capture_warnings(tmp_path: Path) -> None:
    for k, desc in enumerate(["Display P3", "Some printer profile"]):
        level = 60 + 60 * k
        Image.fromarray(np.full((16, 24, 3), level, np.uint8)).save(
            tmp_path / f"f{k}.png", icc_profile=_icc(desc)
        )
    b = load_bracket([tmp_path], exposure_times={"f0.png": 0.01, "f1.png": 0.04})
    codes = {w.code: w for w in b.warnings}
    assert "colour-space-unknown" in codes and "colour-space-differs" in codes
    assert "Some printer profile" in codes["colour-space-unknown"].message
    assert codes["colour-space-unknown"].frames == (1,)


def test_a_p3_source_reaches_another_working_space_in_one_matrix() -> None:
    # working spaces other than sRGB convert inside the merge: from the frames' own primaries
    from hdrcore.merge.colour import colour_conversion

    conv = colour_conversion(None, None, "Rec.2020", source_space="Display P3")
    assert np.allclose(conv.matrix, space_to_space_matrix("Display P3", "Rec.2020"))
    assert not np.allclose(conv.matrix, colour_conversion(None, None, "Rec.2020").matrix)
    assert np.array_equal(space_to_space_matrix("sRGB", "Rec.709"), np.eye(3))

"""14-bit (or 10-, 12-bit) data left unscaled in 16-bit files: read against its own top level,
so its clipped highlights are found and its response is recovered over its whole range."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import tifffile

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline
from hdrcore.synthetic import simulate_bracket
from tests.response.test_frame_encoding import _chromaticity_error

TIMES = (1.0, 4.0, 16.0)


def _write(tmp_path: Path, frames, times=TIMES) -> list[Path]:
    paths = []
    for k, f in enumerate(frames):
        paths.append(tmp_path / f"f{k}.tif")
        tifffile.imwrite(paths[-1], np.asarray(f, np.uint16))
    (tmp_path / "times.txt").write_text(
        "".join(f"{p.name} {t:g}\n" for p, t in zip(paths, times, strict=True))
    )
    return paths


def test_fourteen_bit_levels_in_sixteen_bit_files(tmp_path) -> None:
    sim = simulate_bracket(
        scene="window",
        shape=(160, 240),
        exposure_times=TIMES,
        bits=14,
        response="linear",
        noise_sigma=2.0,
        seed=5,
    )
    b = load_bracket(_write(tmp_path, sim.frames), exposure_times=tmp_path / "times.txt")
    assert b.max_level == 16383 and b.bit_depth == 14
    (w,) = [w for w in b.warnings if w.code == "narrow-container"]
    assert "16383" in w.message and "f2.tif" in w.message
    result = Pipeline(b).run()
    # measured: read against 65535 the response came out a filmic curve (0.77 from linear) and
    # the median chromaticity error against the truth was 0.022-0.045; now the frames are
    # linear-encoded and the merge 0.0002
    assert result.colour["check"]["frame_encoding"]["encoding"] == "linear"
    assert _chromaticity_error(result.radiance, sim.radiance) < 0.001


def test_full_range_and_unclipped_frames_are_left_alone(tmp_path) -> None:
    sim = simulate_bracket(
        scene="window", shape=(60, 90), exposure_times=TIMES, bits=16, response="linear", seed=1
    )
    (tmp_path / "a").mkdir()
    b = load_bracket(_write(tmp_path / "a", sim.frames), exposure_times=tmp_path / "a/times.txt")
    assert b.max_level == 65535 and not [w for w in b.warnings if w.code == "narrow-container"]
    # levels up to 16383 but no clipping pile-up there (a dark 16-bit bracket): 65535 stays
    rng = np.random.default_rng(0)
    dark = [rng.integers(100, 16000, (60, 90, 3)) for _ in TIMES]
    dark[2][0, 0, 0] = 16383
    (tmp_path / "b").mkdir()
    b = load_bracket(_write(tmp_path / "b", dark), exposure_times=tmp_path / "b/times.txt")
    assert b.max_level == 65535

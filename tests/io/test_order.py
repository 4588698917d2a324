"""Frame order: the full exposure (time x ISO x aperture), and the pixels against wrong times."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
import pytest

from hdrcore.cli import main
from hdrcore.io import load_bracket, read_exposure_times
from hdrcore.io.bracket import brightness_order
from hdrcore.synthetic import simulate_bracket, write_bracket

from ._images import gradient, write_jpeg

F = Fraction


@pytest.fixture(scope="module")
def simulated(tmp_path_factory: pytest.TempPathFactory) -> Path:
    """``hdrcore simulate DIR --times 1/1024,1/256,1/64,1/16``: PNGs with EXIF, truth.json."""
    out = tmp_path_factory.mktemp("sim") / "bracket"
    rc = main(["simulate", str(out), "--times", "1/1024,1/256,1/64,1/16", "--size", "96x128"])
    assert rc == 0
    return out


def _times_file(folder: Path, lines: list[tuple[str, str]]) -> Path:
    p = folder / "times.txt"
    p.write_text("".join(f"{n} {t}\n" for n, t in lines))
    return p


def test_iso_bracket_sharing_one_time_is_ordered_by_time_x_iso(tmp_path: Path) -> None:
    # A phone's exposure-compensation bracket: three frames at 1/15 s, ISO 800/500/250.
    spec = [
        ("a.jpg", F(1, 15), 800, 0.45),
        ("b.jpg", F(1, 15), 250, 0.15),
        ("c.jpg", F(1, 10), 800, 0.65),
        ("d.jpg", F(1, 15), 500, 0.3),
    ]
    paths = [
        write_jpeg(tmp_path / n, gradient(scale=s, seed=k), exposure=t, iso=iso)
        for k, (n, t, iso, s) in enumerate(spec)
    ]
    b = load_bracket(paths)
    assert [Path(p).name for p in b.paths] == ["b.jpg", "d.jpg", "a.jpg", "c.jpg"]
    assert b.order_source == "exposure"
    assert b.exif_ratio(0, 1) == pytest.approx(2.0)  # ISO 250 -> 500 at the same time
    # 1/15 -> 1/10 s at ISO 800: 2^(2/3) on the 1/3-stop dial (1.5 as written).
    assert b.exif_ratio(2, 3) == pytest.approx(2 ** (2 / 3))
    assert b.exif_ratio(2, 3, snapped=False) == pytest.approx(1.5)
    iso = next(w for w in b.warnings if w.code == "iso-changed")
    assert "b.jpg, d.jpg, a.jpg share 1/15 s: only their ISO differs" in iso.message
    assert "includes the ISO change" in iso.message
    assert "duplicate-exposure" not in b.warning_codes()
    assert not {"times-swapped", "out-of-order"} & set(b.warning_codes())


def test_same_full_exposure_is_a_duplicate_warning(tmp_path: Path) -> None:
    # 1/30 s at ISO 400 and 1/15 s at ISO 200: the same exposure.
    paths = [
        write_jpeg(tmp_path / "a.jpg", gradient(scale=0.5, seed=0), exposure=F(1, 30), iso=400),
        write_jpeg(tmp_path / "b.jpg", gradient(scale=0.5, seed=1), exposure=F(1, 15), iso=200),
        write_jpeg(tmp_path / "c.jpg", gradient(scale=0.9, seed=2), exposure=F(1, 4), iso=200),
    ]
    b = load_bracket(paths)
    dup = [w for w in b.warnings if w.code == "duplicate-exposure"]
    assert len(dup) == 1 and dup[0].frames == (0, 1)
    assert "a.jpg" in dup[0].message and "b.jpg" in dup[0].message
    assert "1/30 s, ISO 400" in dup[0].message and "1/15 s, ISO 200" in dup[0].message
    assert b.exif_ratio(0, 1) == pytest.approx(1.0)
    assert not {"times-swapped", "out-of-order"} & set(b.warning_codes())


def test_swapped_times_are_detected_and_frames_ordered_by_brightness(simulated: Path) -> None:
    truth = read_exposure_times(simulated / "exposure_times.txt")
    assert truth["frame02.png"] == F(1, 64)
    swapped = _times_file(
        simulated.parent,
        [
            ("frame00.png", "1/1024"),
            ("frame01.png", "1/256"),
            ("frame02.png", "1/16"),
            ("frame03.png", "1/64"),
        ],
    )
    b = load_bracket([simulated], exposure_times=swapped)
    # The pixels are the truth: the frames stay in brightness order...
    assert [Path(p).name for p in b.paths] == [f"frame0{k}.png" for k in range(4)]
    assert b.order_source == "brightness"
    # ... each with the time it was given, so the swapped pair's ratio from the times is < 1.
    assert b.exposure_times == (1 / 1024, 1 / 256, 1 / 16, 1 / 64)
    assert b.exif_ratio(2, 3) == pytest.approx(0.25)
    (w,) = [w for w in b.warnings if w.code == "times-swapped"]
    assert w.message.startswith(
        "frame03.png (1/64 s) is brighter than frame02.png (1/16 s): the times look swapped; "
        "the frames are ordered by brightness"
    )
    assert w.frames == (2, 3)
    assert "out-of-order" not in b.warning_codes()
    # The correct file gives no such warning.
    good = load_bracket([simulated], exposure_times=simulated / "exposure_times.txt")
    assert good.order_source == "exposure"
    assert not {"times-swapped", "out-of-order"} & set(good.warning_codes())


def test_swapped_times_given_out_of_order_files(simulated: Path) -> None:
    swapped = {
        "frame00.png": F(1, 256),
        "frame01.png": F(1, 1024),
        "frame02.png": F(1, 64),
        "frame03.png": F(1, 16),
    }
    files = [simulated / f"frame0{k}.png" for k in (3, 1, 0, 2)]
    b = load_bracket(files, exposure_times=swapped)
    assert [Path(p).name for p in b.paths] == [f"frame0{k}.png" for k in range(4)]
    assert b.input_order == (2, 1, 3, 0)
    (w,) = [w for w in b.warnings if w.code == "times-swapped"]
    assert "frame01.png (1/1024 s) is brighter than frame00.png (1/256 s)" in w.message
    assert b.exif_ratio(0, 1) == pytest.approx(0.25)


def test_scrambled_times_are_out_of_order(simulated: Path) -> None:
    # Three times rotated: not a clean swap.
    rotated = {
        "frame00.png": F(1, 64),
        "frame01.png": F(1, 1024),
        "frame02.png": F(1, 256),
        "frame03.png": F(1, 16),
    }
    b = load_bracket([simulated], exposure_times=rotated)
    assert [Path(p).name for p in b.paths] == [f"frame0{k}.png" for k in range(4)]
    (w,) = [w for w in b.warnings if w.code == "out-of-order"]
    assert "frame01.png (1/1024 s) is brighter than frame00.png (1/64 s)" in w.message
    assert "ordered by brightness, darkest first: frame00.png, frame01.png" in w.message
    assert "times-swapped" not in b.warning_codes()


def test_jpeg_brighter_frame_claiming_the_shortest_time(tmp_path: Path) -> None:
    paths = []
    for k, t in enumerate([F(1, 50), F(1, 10), F(1, 500)]):
        paths.append(
            write_jpeg(tmp_path / f"f{k}.jpg", gradient(scale=0.3 * (k + 1), seed=k), exposure=t)
        )
    b = load_bracket(paths)
    assert [Path(p).name for p in b.paths] == ["f0.jpg", "f1.jpg", "f2.jpg"]
    assert "out-of-order" in b.warning_codes()


def test_black_and_saturated_frames_do_not_reorder(tmp_path: Path) -> None:
    # 28 stops in 2-stop steps, 12 bits: the darkest frames are black (a fraction of a level
    # on average), the longest saturated; a duplicate of the darkest time too. Uninformative
    # frames never contradict the times.
    times = (2.0**-16, 2.0**-16, *(2.0**-14 * 4.0**k for k in range(14)))
    sim = simulate_bracket(
        scene="patches",
        shape=(64, 96),
        exposure_times=times,
        bits=12,
        noise_sigma=1.0,
        key=1.0,
        seed=3,
    )
    write_bracket(tmp_path, sim, fmt="png")
    b = load_bracket([tmp_path], exposure_times=tmp_path / "exposure_times.txt")
    means = [f.mean_level() for f in b.frames]
    assert means[0] < 0.001 and means[1] < 0.001 and means[-1] > 0.995 and means[-2] > 0.99
    codes = b.warning_codes()
    assert not {"times-swapped", "out-of-order"} & set(codes), b.warnings
    assert b.order_source == "exposure"
    assert "duplicate-exposure" in codes
    assert b.exposure_times == tuple(sorted(times))


def test_brightness_order_helper_keeps_an_uncontradicted_order(simulated: Path) -> None:
    b = load_bracket([simulated])
    frames = list(b.frames)
    assert brightness_order(frames, [0, 1, 2, 3]) == ([0, 1, 2, 3], [])
    order, contradicted = brightness_order(frames, [0, 2, 1, 3])
    assert order == [0, 1, 2, 3] and contradicted == [(2, 1)]


# --- real photographs ---------------------------------------------------------------------------


@pytest.mark.shared
def test_xperia_order_is_time_x_iso_and_matches_brightness(capsys) -> None:
    from ..conftest import shared_dir

    d = shared_dir("handheld-xperia-library")
    b = load_bracket([d])
    expected = [
        line.split()[0]
        for line in (d / "iso100_equivalent_times.txt").read_text().splitlines()
        if line.strip() and not line.startswith("#")
    ]
    names = [Path(p).name for p in b.paths]
    means = [f.mean_level() for f in b.frames]
    iso0 = b.frames[0].meta.iso
    iso100 = [e * iso0 / 100 for e in b.exif_exposures()]  # type: ignore[operator]
    with capsys.disabled():
        print("\nxperia, darkest first: name, time, ISO, time x ISO/100 (snapped), mean level")
        for f, e, m in zip(b.frames, iso100, means, strict=True):
            print(f"  {f.name} {f.meta.exposure_time} s ISO {f.meta.iso} {e:.4f} s {m:.4f}")
    assert names == expected
    assert b.order_source == "exposure"
    assert all(np.diff(means) > 0)  # the order by exposure is the order by brightness
    assert not {"times-swapped", "out-of-order", "duplicate-exposure"} & set(b.warning_codes())
    iso = next(w for w in b.warnings if w.code == "iso-changed")
    assert (
        "20240401_185055.JPG, 20240401_185043.JPG, 20240401_185036.JPG share 1/15 s" in iso.message
    )
    assert "20240401_185005.JPG, 20240401_184958.JPG share 1/4 s: only their ISO differs" in (
        iso.message
    )
    assert b.apex_sequence == "1/3-stop"

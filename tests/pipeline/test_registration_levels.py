"""The registration reads its thresholds snapped to the bracket's quantile ladder
(:mod:`hdrcore.registration.thresholds`, the pipeline's ``registration_levels`` step): a slider
step inside a run keeps the cached registration, and the result still equals a fresh run's."""

from __future__ import annotations

import numpy as np
import pytest
import tifffile

from hdrcore.io import load_bracket
from hdrcore.pipeline import Pipeline, PipelineParams
from hdrcore.registration.thresholds import snap_levels
from hdrcore.synthetic import simulate_bracket

from ._compare import differences


@pytest.fixture(scope="module")
def sixteen_bit(tmp_path_factory: pytest.TempPathFactory):
    """A hand-held 14-bit linear bracket in 16-bit TIFF files (the bench's kind, small)."""
    sim = simulate_bracket(
        scene="window",
        shape=(120, 180),
        exposure_times=(1.0, 4.0, 16.0),
        bits=14,
        response="linear",
        noise_sigma=2.0,
        max_shift=2,
        max_rotation_deg=0.3,
        seed=4,
    )
    out = tmp_path_factory.mktemp("sixteen")
    names = []
    for k, f in enumerate(sim.frames):
        tifffile.imwrite(out / f"frame{k}.tif", f.astype(np.uint16))
        names.append(f"frame{k}.tif")
    (out / "exposure_times.txt").write_text(
        "".join(f"{n} {t:g}\n" for n, t in zip(names, sim.exposure_times, strict=True))
    )
    return lambda: load_bracket([out / n for n in names], exposure_times=out / "exposure_times.txt")


def _snapped(result) -> tuple[float, float]:
    return snap_levels(result.histograms.counts[:, 1], result.saturation, result.noise_floor)


def test_a_step_inside_a_run_keeps_the_registration(sixteen_bit) -> None:
    pl = Pipeline(sixteen_bit(), PipelineParams(response="linear"))
    first = pl.run(until="registration")
    assert first.registration is not None
    s = first.saturation
    moved = [first.params.replace(saturation=s - d) for d in (1.0, 2.0, 3.0, 5.0, 8.0)]
    kept = [p for p in moved if _snapped(pl.run(p, until="ratios")) == _snapped(first)]
    assert kept  # some steps stay inside the run (the test's premise)
    for p in kept:
        again = pl.run(p, until="registration")
        assert "registration" not in again.stages_run
        assert "ratios" in again.stages_run  # the ratios read the requested level
        fresh = Pipeline(sixteen_bit(), p).run(p, until="registration")
        assert differences(again.registration, fresh.registration) == []


def test_a_step_out_of_the_run_registers_again(sixteen_bit) -> None:
    pl = Pipeline(sixteen_bit(), PipelineParams(response="linear"))
    first = pl.run(until="registration")
    far = first.params.replace(saturation=0.9 * first.saturation)
    assert _snapped(pl.run(far, until="ratios")) != _snapped(first)
    again = pl.run(far, until="registration")
    assert "registration" in again.stages_run
    fresh = Pipeline(sixteen_bit(), far).run(far, until="preview")
    assert differences(pl.run(far), fresh) == []


def test_the_registration_reads_the_snapped_levels(sixteen_bit) -> None:
    """The registration at the requested thresholds is the one at the snapped thresholds
    requested directly (the snapped pair is a fixed point of the ladder)."""
    # the EXIF times: the registration's starting ratios then do not follow the requested
    # levels (the histogram ratios do: a 0.5 % cut of this small frame's darkest samples
    # moves them by 2 %)
    pl = Pipeline(sixteen_bit(), PipelineParams(response="linear", times="exif"))
    first = pl.run(until="registration")
    s2, f2 = _snapped(first)
    assert (s2, f2) != (first.saturation, first.noise_floor)
    direct = Pipeline(sixteen_bit(), first.params.replace(saturation=s2, noise_floor=f2))
    other = direct.run(until="registration")
    assert _snapped(other) == (s2, f2)
    assert differences(first.registration, other.registration) == []


def test_one_level_steps_of_an_8_bit_bracket_keep_the_registration(tmp_path) -> None:
    """8-bit frames: 1/512 of the range is under a level, yet the ladder's runs span up to
    MIN_STEP_LEVELS levels (and the starting ratios are read to 1/64 stop), so one-level
    saturation steps keep the registration most of the time; a kept one equals a fresh run."""
    from hdrcore.registration.thresholds import MIN_STEP_LEVELS
    from tests.hdrview._brackets import write_png_bracket

    files = write_png_bracket(tmp_path / "b", shape=(120, 180))
    pl = Pipeline(load_bracket(files))
    first = pl.run(until="registration")
    assert first.registration is not None
    top = float(np.floor(first.saturation))
    steps = [top - d for d in range(1, 3 * MIN_STEP_LEVELS + 1)]
    kept = []
    for s in steps:
        p = first.params.replace(saturation=s)
        if "registration" not in pl.run(p, until="registration").stages_run:
            kept.append(p)
    assert len(kept) >= len(steps) // 2
    p = kept[-1]
    fresh = Pipeline(load_bracket(files), p).run(p, until="registration")
    assert differences(pl.run(p, until="registration").registration, fresh.registration) == []


def test_a_held_registration_is_the_last_runs_motion(sixteen_bit) -> None:
    """``hold_registration``: a step out of the run merges on the last registration (from the
    cache: nothing registers) with the new levels; the real run registers afterwards."""
    pl = Pipeline(sixteen_bit(), PipelineParams(response="linear"))
    first = pl.run()
    assert first.registration_inputs is not None
    far = first.params.replace(saturation=0.9 * first.saturation)
    quick = pl.run(far, until="ratios")
    assert quick.registration_inputs != first.registration_inputs
    assert not pl.registration_cached(quick.params)
    held = quick.params.replace(hold_registration=first.registration_inputs)
    assert pl.registration_cached(held)
    interim = pl.run(held, checks="later")
    assert "registration" not in interim.stages_run and "merge" in interim.stages_run
    assert interim.registration is first.registration
    assert interim.saturation == quick.saturation
    assert interim.registration_inputs == first.registration_inputs
    # its merge is the one a pipeline given that motion makes with the new levels
    fixed = Pipeline(sixteen_bit(), far, registration=first.registration).run(far)
    assert np.array_equal(interim.radiance, fixed.radiance)
    assert not np.array_equal(interim.radiance, first.radiance)
    # the real step registers again and equals a fresh run of its parameters
    final = pl.run(far)
    assert "registration" in final.stages_run
    assert final.registration_inputs == quick.registration_inputs
    assert differences(final, Pipeline(sixteen_bit(), far).run(far)) == []
    assert pl.registration_cached(final.params) and pl.registration_cached(held)


@pytest.mark.parametrize(
    "held",
    [((240.0,), (4.0, 4.0)), ((240.0, 10.0), (4.0,)), "levels", ((240.0, 10.0), None)],
)
def test_a_held_registration_of_another_shape_is_refused(sixteen_bit, held) -> None:
    from hdrcore.errors import ParameterError

    pl = Pipeline(sixteen_bit(), PipelineParams(response="linear"))
    with pytest.raises(ParameterError, match="hold_registration"):
        pl.run(PipelineParams(response="linear", hold_registration=held), until="ratios")

"""A small simulated folder for the batch tests: four 3-frame brackets (64x48 JPEG, EXIF
written as a camera would) with a single shot between them, and a bad bracket in the middle
(its middle frame cut short after the header: grouped like the others, fails to decode)."""

from __future__ import annotations

from pathlib import Path

import pytest

from hdrcore.batch.simulate import SimShot, simulate_session, write_session


def bad_frame(sim: list[SimShot]) -> str:
    """The frame cut short: the middle one of the third bracket."""
    brackets = sorted({s.group for s in sim if s.kind == "bracket"})
    return [s for s in sim if s.group == brackets[2]][1].name


def make_folder(folder: Path) -> list[SimShot]:
    sim = simulate_session(
        11, n_brackets=5, sizes=(3,), singles=0.4, bursts=0.0, gap_range=(0.5, 2.0)
    )
    paths = write_session(folder, sim, seed=3, shape=(48, 64))
    bad = folder / bad_frame(sim)
    data = bad.read_bytes()
    bad.write_bytes(data[: int(len(data) * 0.6)])
    assert len(paths) == len(sim) and any(s.kind == "single" for s in sim)
    return sim


@pytest.fixture(scope="session")
def sim_folder(tmp_path_factory) -> tuple[Path, list[SimShot]]:
    folder = tmp_path_factory.mktemp("shots")
    return folder, make_folder(folder)

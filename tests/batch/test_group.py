"""Grouping a folder's shots into brackets (hdrcore.batch.group), from metadata alone.

The shots are made from simulated sessions (hdrcore.batch.simulate) without writing files:
the truth is which frames one bracket took. Cases of issue 19: 3/5/7/9-frame brackets in
darker-first, brighter-first and centre-out (0, -, +) orders, single shots and bursts of equal
exposures between them, pauses of 0.2-5 s, whole-second clocks, several cameras.
"""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from hdrcore.batch import bracket_order, group_shots, make_plan, read_plan
from hdrcore.batch.scan import Shot
from hdrcore.batch.simulate import bracket_offsets, simulate_session
from hdrcore.errors import InputError, ParameterError


def _shots(sim, *, folder="/d", subsec=True, camera="SimCam S1", size=(64, 48), offset=0.0):
    out = []
    for s in sim:
        t = 1.0e9 + offset + s.time
        out.append(
            Shot(
                path=f"{folder}/{s.name}",
                folder=folder,
                time=t if subsec else float(int(t)),
                subsec=subsec,
                exposure_time=float(s.exposure_time),
                iso=100.0,
                f_number=8.0,
                exposure_bias=float(s.bias),
                camera=camera,
                size=size,
            )
        )
    return out


def _truth(sim, folder="/d"):
    by = {}
    for s in sim:
        if s.kind == "bracket":
            by.setdefault(s.group, set()).add(f"{folder}/{s.name}")
    return {frozenset(v) for v in by.values()}


def _found(groups):
    return {frozenset(g.paths) for g in groups if g.is_bracket}


@pytest.mark.parametrize(
    "order, want",
    [
        ([0, -1, 1], "centre-out"),
        ([0, 1, -1, 2, -2], "centre-out"),
        ([2, 1, 0, -1], "darker"),
        ([-3, 0, 3], "brighter"),
        ([0, -1, 1, -2], "centre-out"),
        ([-1, 0, 1, -2], None),
        ([0, 0, 1], None),
        ([1, -1, 0], None),
        ([0, 0.1], None),
    ],
)
def test_bracket_orders(order, want):
    assert bracket_order(order) == want


def test_offsets_are_the_named_orders():
    assert bracket_offsets(5, "centre-out") == [0, -1, 1, -2, 2]
    assert bracket_offsets(3, "darker") == [1, 0, -1]
    assert bracket_offsets(3, "brighter", step=2) == [-2, 0, 2]


@pytest.mark.parametrize("seed", range(6))
def test_mixed_sessions_grouped_exactly(seed):
    sim = simulate_session(seed, n_brackets=15)
    groups = group_shots(_shots(sim))
    assert _found(groups) == _truth(sim)
    # every single shot and every burst frame is left alone
    singles = {g.paths[0] for g in groups if not g.is_bracket}
    assert singles == {f"/d/{s.name}" for s in sim if s.kind != "bracket"}


def test_whole_second_clock_still_grouped():
    """Without subseconds (1 s resolution) the exposure order alone separates the brackets."""
    sim = simulate_session(11, n_brackets=12, gap_range=(0.2, 1.0))
    assert _found(group_shots(_shots(sim, subsec=False))) == _truth(sim)


def test_fixed_gap_rule_joins_close_brackets():
    """HDRMerge's 2 s rule merges two brackets 0.3 s apart; the exposure order separates them."""
    sim = simulate_session(3, n_brackets=6, singles=0, bursts=0, gap_range=(0.3, 0.3))
    shots = _shots(sim)
    assert _found(group_shots(shots)) == _truth(sim)
    hdrmerge = _found(group_shots(shots, "gap", gap=2.0))
    assert len(hdrmerge) == 1 and hdrmerge != _truth(sim)


def test_long_exposures_split_by_fixed_gap_not_by_signals():
    """A 3-frame bracket of 4, 8, 16 s with 2.5 s between frames (a slow camera writing to its
    card): HDRMerge's gap measured end-to-start still splits at 2 s; the stream's own
    in-bracket gaps set the scale here."""
    sim = simulate_session(5, n_brackets=4, sizes=(3,), singles=0, bursts=0, gap_range=(30.0, 40.0))
    shots = []
    t = 0.0
    for s in sim:
        shots.append(
            Shot(
                path=f"/d/{s.name}",
                folder="/d",
                time=1e9 + t,
                subsec=True,
                exposure_time=float(s.exposure_time) * 256,
                iso=100.0,
                f_number=8.0,
                exposure_bias=float(s.bias),
                camera="C",
                size=(64, 48),
            )
        )
        t += float(s.exposure_time) * 256 + (2.5 if s.name != sim[-1].name else 0)
        if s is not sim[-1] and sim[sim.index(s) + 1].group != s.group:
            t += 35.0
    assert _found(group_shots(shots)) == _truth(sim)
    assert _found(group_shots(shots, "gap", gap=2.0)) == set()


def test_streams_never_mix_cameras_or_sizes():
    a = simulate_session(1, n_brackets=4, singles=0, bursts=0)
    b = simulate_session(2, n_brackets=4, singles=0, bursts=0, prefix="DSC_")
    shots = _shots(a) + _shots(b, camera="Other", offset=0.05)  # interleaved in time
    assert _found(group_shots(shots)) == _truth(a) | _truth(b)
    shots = _shots(a) + _shots(b, size=(32, 24), offset=0.05)
    assert _found(group_shots(shots)) == _truth(a) | _truth(b)


def test_no_exposure_metadata_groups_the_folder():
    shots = [Shot(path=f"/m/f{k}.png", folder="/m") for k in range(4)]
    shots += [Shot(path=f"/n/g{k}.png", folder="/n") for k in range(3)]
    groups = group_shots(shots)
    assert sorted(len(g.shots) for g in groups) == [3, 4]
    assert all("no exposures" in g.reason for g in groups)


def test_forced_rules_and_their_errors():
    sim = simulate_session(4, n_brackets=5)
    shots = _shots(sim)
    groups = group_shots(shots, "count", size=3)
    assert [len(g.shots) for g in groups[:-1]] == [3] * (len(groups) - 1)
    with pytest.raises(ParameterError, match="group size"):
        group_shots(shots, "count", size=0)
    with pytest.raises(ParameterError, match="non-negative"):
        group_shots(shots, "gap", gap=-1)
    with pytest.raises(ParameterError, match="unknown grouping method 'magic'.*'signals'"):
        group_shots(shots, "magic")


def test_plan_round_trip_and_edit(tmp_path):
    files = []
    for k in range(6):
        p = tmp_path / f"IMG_{k:04d}.jpg"
        p.write_bytes(b"x")
        files.append(p)
    shots = [
        Shot(
            path=str(p),
            folder=str(tmp_path),
            time=1e9 + k * 0.2,
            subsec=True,
            exposure_time=2.0 ** [0, -1, 1, 0, -1, 1][k] / 64,
            camera="C",
            size=(4, 4),
        )
        for k, p in enumerate(files)
    ]
    plan = make_plan(group_shots(shots))
    assert [b.name for b in plan.brackets] == ["IMG_0000-0002", "IMG_0003-0005"]
    doc = plan.to_json()
    doc["brackets"][0]["name"] = "first"
    doc["brackets"][1]["files"] = [Path(f).name for f in doc["brackets"][1]["files"]][:2]
    pf = tmp_path / "plan.json"
    pf.write_text(json.dumps(doc))
    again = read_plan(pf)
    assert again.brackets[0].name == "first"
    assert again.brackets[1].files == (str(files[3]), str(files[4]))


@pytest.mark.parametrize(
    "doc, match",
    [
        ("not json", "not JSON"),
        ({"x": 1}, "not a batch plan"),
        ({"brackets": [{"files": ["IMG_0000.jpg"]}]}, "bracket 1 has 1 file"),
        ({"brackets": [{"files": ["missing.jpg", "IMG_0000.jpg"]}]}, "bracket 1: no such file"),
        (
            {
                "brackets": [
                    {"files": ["IMG_0000.jpg", "IMG_0001.jpg"]},
                    {"files": ["IMG_0001.jpg", "IMG_0002.jpg"]},
                ]
            },
            "IMG_0001.jpg is also in",
        ),
        (
            {"brackets": [{"name": "a/b", "files": ["IMG_0000.jpg", "IMG_0001.jpg"]}]},
            "cannot be a file name",
        ),
    ],
)
def test_bad_plan_files_are_named(tmp_path, doc, match):
    for k in range(3):
        (tmp_path / f"IMG_{k:04d}.jpg").write_bytes(b"x")
    pf = tmp_path / "plan.json"
    pf.write_text(doc if isinstance(doc, str) else json.dumps(doc))
    with pytest.raises(InputError, match=match) as err:
        read_plan(pf)
    assert str(pf) in str(err.value)

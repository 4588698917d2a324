"""Grouping on a folder that mixes the real brackets of ../shared/data (symbolic links in a
temporary folder, never copies): the Xperia (8 frames, 4-16 s apart, unequal steps), the
Pixel 7 (6 frames, 10-13 s apart), frobisher (3 frames of 1/8-8 s), memorial (16 PNG without
any EXIF) and two Canon CRW singles of two cameras (LibRaw's header: no TIFF EXIF)."""

from __future__ import annotations

import pytest

from hdrcore.batch import group_shots, scan_shots

from ..conftest import SHARED_DATA

pytestmark = pytest.mark.shared

BRACKETS = (
    "frobisher-colour-hdri",
    "handheld-pixel7-lab",
    "handheld-xperia-library",
    "memorial-debevec",
)
SINGLES = ("raw-singles-cc0-canon-crw",)


def test_mixed_real_folder_is_grouped(tmp_path):
    if not all((SHARED_DATA / n).is_dir() for n in BRACKETS + SINGLES):
        pytest.skip(f"real data not available at {SHARED_DATA}")
    truth = set()
    for name in BRACKETS + SINGLES:
        members = set()
        for f in sorted((SHARED_DATA / name).iterdir()):
            if f.suffix.lower() in (".jpg", ".png", ".crw"):
                (tmp_path / f.name).symlink_to(f)
                members.add(str(tmp_path / f.name))
        if name in BRACKETS:
            truth.add(frozenset(members))
    shots = scan_shots([tmp_path])
    groups = group_shots(shots)
    assert {frozenset(g.paths) for g in groups if g.is_bracket} == truth
    assert sorted(g.paths[0].rsplit("/", 1)[-1] for g in groups if not g.is_bracket) == [
        "G2_CRW_0304.CRW",
        "S40_CRW_0101.CRW",
    ]
    # HDRMerge's 2 s rule finds only frobisher's
    hdrmerge = {frozenset(g.paths) for g in group_shots(shots, "gap", gap=2.0) if g.is_bracket}
    assert len(hdrmerge & truth) == 1

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

"""The preview's colour-science constants, kept in the user's cache folder between processes."""

from __future__ import annotations

import numpy as np

from hdrcore import tonemap


def test_constants_come_from_colour_science_and_are_cached(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    tonemap._colour_constants.cache_clear()
    y, lut = tonemap._colour_constants()
    want_y, want_lut = tonemap._compute_constants()
    np.testing.assert_array_equal(y, want_y)
    np.testing.assert_array_equal(lut, want_lut)
    assert abs(float(y[1]) - 0.7152) < 1e-4  # Rec.709 green
    path = tonemap._cache_file()
    assert path is not None and path.startswith(str(tmp_path))
    # A later process reads the file: here, a stand-in table proves it is the one used.
    tonemap._colour_constants.cache_clear()
    marked = want_lut.copy()
    marked[1] = 7
    np.savez(path, luminance=want_y, srgb=marked)
    assert tonemap._colour_constants()[1][1] == 7
    # A damaged file is computed again.
    tonemap._colour_constants.cache_clear()
    with open(path, "wb") as f:
        f.write(b"not a numpy file")
    np.testing.assert_array_equal(tonemap._colour_constants()[1], want_lut)
    tonemap._colour_constants.cache_clear()


def test_unwritable_cache_is_not_an_error(tmp_path, monkeypatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))  # a file where a folder should be
    tonemap._colour_constants.cache_clear()
    y, lut = tonemap._colour_constants()
    assert lut.shape == (65536,) and lut[-1] == 255
    tonemap._colour_constants.cache_clear()

"""The preview's colour-science constants, kept in the user's cache folder between processes."""

from __future__ import annotations

import numpy as np

from hdrcore import _colour_cache, tonemap


def test_constants_come_from_colour_science_and_are_cached(tmp_path, monkeypatch) -> None:
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    _colour_cache.clear_memory()
    y, lut = tonemap._colour_constants()
    # The truth, written out here (IEC 61966-2-1): the Y row of sRGB's RGB -> XYZ matrix and
    # the sRGB encoding, sampled at 65536 points and rounded to 8 bits.
    np.testing.assert_allclose(y, [0.2126, 0.7152, 0.0722], atol=1e-4)
    x = np.linspace(0.0, 1.0, 65536)
    srgb = np.where(x <= 0.0031308, 12.92 * x, 1.055 * x ** (1 / 2.4) - 0.055)
    want_lut = np.clip(np.rint(srgb * 255.0), 0, 255).astype(np.uint8)
    assert lut.dtype == np.uint8 and lut.shape == (65536,)
    assert np.count_nonzero(lut != want_lut) <= 8  # rounding at exact half levels, at most
    assert np.abs(lut.astype(int) - want_lut).max() <= 1
    want_y = y
    path = tonemap._cache_file()
    assert path is not None and path.startswith(str(tmp_path))
    # A later process reads the file: here, a stand-in table proves it is the one used.
    _colour_cache.clear_memory()
    marked = want_lut.copy()
    marked[1] = 7
    np.savez(path, luminance=want_y, srgb=marked)
    assert tonemap._colour_constants()[1][1] == 7
    # A damaged file is computed again.
    _colour_cache.clear_memory()
    with open(path, "wb") as f:
        f.write(b"not a numpy file")
    np.testing.assert_array_equal(tonemap._colour_constants()[1], want_lut)
    _colour_cache.clear_memory()


def test_unwritable_cache_is_not_an_error(tmp_path, monkeypatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))  # a file where a folder should be
    _colour_cache.clear_memory()
    y, lut = tonemap._colour_constants()
    assert lut.shape == (65536,) and lut[-1] == 255
    _colour_cache.clear_memory()

"""colour-science's sRGB decoding kept in the user's cache folder (hdrcore._colour_cache): the
same values as colour-science's, read back by a later process without importing it."""

from __future__ import annotations

import os
import subprocess
import sys

import numpy as np
import pytest

from hdrcore import _colour_cache
from hdrcore.exposure import srgb_lut
from hdrcore.response import srgb_response


@pytest.fixture
def cache_home(tmp_path, monkeypatch):
    monkeypatch.setenv("XDG_CACHE_HOME", str(tmp_path))
    _colour_cache.clear_memory()
    yield tmp_path
    _colour_cache.clear_memory()


@pytest.mark.parametrize("m", [255, 4095])
def test_srgb_tables_are_colour_sciences(cache_home, m) -> None:
    import colour

    v = np.arange(m + 1) / m
    want = np.asarray(colour.models.eotf_sRGB(v), np.float64)
    np.testing.assert_array_equal(_colour_cache.srgb_eotf(m), want)
    np.testing.assert_array_equal(srgb_lut(m), want / want[-1])
    np.testing.assert_array_equal(
        np.asarray(colour.cctf_decoding(v, function="sRGB"), np.float64), want
    )
    g = srgb_response(m, 3).g
    assert g.shape == (3, m + 1)
    np.testing.assert_allclose(g[1], want / want[-1], atol=1e-15)
    path = _colour_cache.cache_file(f"srgb-eotf-{m}")
    assert path is not None and path.startswith(str(cache_home)) and os.path.isfile(path)


def test_the_file_is_read_and_a_damaged_one_made_again(cache_home) -> None:
    want = _colour_cache.srgb_eotf(255).copy()
    path = _colour_cache.cache_file("srgb-eotf-255")
    marked = want.copy()
    marked[1] = 0.5  # a stand-in table proves the file is the one used
    np.savez(path, eotf=marked)
    _colour_cache.clear_memory()
    assert _colour_cache.srgb_eotf(255)[1] == 0.5
    for damage in (b"not a numpy file", None):
        if damage is None:
            np.savez(path, eotf=want[:10])  # the wrong shape: stale
        else:
            with open(path, "wb") as f:
                f.write(damage)
        _colour_cache.clear_memory()
        np.testing.assert_array_equal(_colour_cache.srgb_eotf(255), want)
    # ... and written again
    _colour_cache.clear_memory()
    with np.load(path) as z:
        np.testing.assert_array_equal(z["eotf"], want)


def test_an_unwritable_cache_is_not_an_error(tmp_path, monkeypatch) -> None:
    blocker = tmp_path / "file"
    blocker.write_text("x")
    monkeypatch.setenv("XDG_CACHE_HOME", str(blocker))  # a file where a folder should be
    _colour_cache.clear_memory()
    try:
        g = _colour_cache.srgb_eotf(255)
        assert g.shape == (256,) and g[-1] == 1.0 and g[0] == 0.0
    finally:
        _colour_cache.clear_memory()


def test_a_later_process_does_not_import_colour_science(cache_home) -> None:
    """The point of the cache: a JPEG bracket's sRGB candidate and the preview's tables in a new
    process without colour-science's 0.8-0.9 s import (it imports matplotlib)."""
    code = (
        "import sys; from hdrcore.response import srgb_response; "
        "from hdrcore.exposure import srgb_lut; from hdrcore import tonemap; "
        "srgb_response(255, 3); srgb_lut(255); tonemap._colour_constants(); "
        "print('colour' in sys.modules)"
    )
    env = dict(os.environ, XDG_CACHE_HOME=str(cache_home))
    first = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    second = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True)
    assert first.returncode == 0 and second.returncode == 0, first.stderr + second.stderr
    assert first.stdout.strip() == "True"  # computed by colour-science, then kept
    assert second.stdout.strip() == "False"

"""Area downsampling of previews."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.resample import downsample_area, downsample_factor


@pytest.mark.parametrize("factor", [1, 2, 3, 5])
def test_block_means(factor: int) -> None:
    rng = np.random.default_rng(factor)
    x = rng.random((23, 31, 3)).astype(np.float32)
    h, w = 23 // factor, 31 // factor
    expected = x[: h * factor, : w * factor].reshape(h, factor, w, factor, 3).mean(axis=(1, 3))
    np.testing.assert_allclose(downsample_area(x, factor), expected, rtol=1e-6)


def test_nan_ignored_within_a_block() -> None:
    x = np.ones((4, 4), np.float32)
    x[0, 0] = np.nan
    x[0, 1] = 3.0
    out = downsample_area(x, 2)
    assert out[0, 0] == pytest.approx(5.0 / 3.0)
    assert np.all(out[1:, :] == 1.0)


def test_factor_and_errors() -> None:
    assert downsample_factor((4000, 6000), 2048) == 3
    assert downsample_factor((100, 100), None) == 1
    with pytest.raises(ParameterError, match="max_side must be >= 1"):
        downsample_factor((10, 10), 0)
    with pytest.raises(ParameterError, match="smaller than the downsampling factor"):
        downsample_area(np.zeros((2, 2), np.float32), 4)


@pytest.mark.parametrize("shape, factor", [((23, 31, 3), 3), ((41, 60, 3), 2), ((40, 61), 4)])
def test_compiled_pass_matches_the_numpy_path(monkeypatch, shape, factor) -> None:
    """The compiled pass sums in numpy's order: bit for bit the numpy path's result; blocks with
    NaNs take the mean of their other values (NaN when none)."""
    import hdrcore.resample as resample

    rng = np.random.default_rng(7)
    x = (10.0 ** rng.uniform(-3, 3, shape)).astype(np.float32)
    compiled = downsample_area(x, factor)
    x_nan = x.copy()
    x_nan[0, 1] = np.nan
    x_nan[factor : 2 * factor, factor : 2 * factor] = np.nan
    compiled_nan = downsample_area(x_nan, factor)
    monkeypatch.setattr(resample, "AVAILABLE", False)
    np.testing.assert_array_equal(compiled, downsample_area(x, factor))
    with np.errstate(invalid="ignore"), pytest.warns(RuntimeWarning):
        reference = downsample_area(x_nan, factor)
    np.testing.assert_allclose(compiled_nan, reference, rtol=1e-6)
    assert np.isnan(compiled_nan[1, 1]).all() and not np.isnan(compiled_nan[0, 0]).any()

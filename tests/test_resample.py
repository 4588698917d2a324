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

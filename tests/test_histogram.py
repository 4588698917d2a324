"""Histograms at native bit depth (hdrcore.histogram)."""

from __future__ import annotations

import numpy as np
import pytest

from hdrcore.errors import ParameterError
from hdrcore.histogram import auto_stride, cumulative, histogram, histograms


def test_counts_every_level_at_native_depth() -> None:
    rng = np.random.default_rng(1)
    for max_level in (255, 4095, 16383):
        a = rng.integers(0, max_level + 1, (64, 96)).astype(np.uint16)
        h = histogram(a, max_level)
        assert h.shape == (max_level + 1,)
        assert h.dtype == np.int64
        assert h.sum() == a.size
        np.testing.assert_array_equal(h, np.bincount(a.ravel(), minlength=max_level + 1))


def test_mask_and_channels() -> None:
    rng = np.random.default_rng(2)
    a = rng.integers(0, 256, (32, 48, 3)).astype(np.uint16)
    mask = np.zeros((32, 48), bool)
    mask[:10] = True
    hs = histograms(a, 255, mask)
    assert hs.shape == (3, 256)
    for c in range(3):
        np.testing.assert_array_equal(hs[c], histogram(a[..., c], 255, mask))
        assert hs[c].sum() == mask.sum()


def test_stride_subsamples() -> None:
    a = np.arange(100 * 100, dtype=np.uint16).reshape(100, 100) % 256
    assert histogram(a, 255, stride=2).sum() == 50 * 50
    assert auto_stride(24_000_000, 6_000_000) == 2
    assert auto_stride(1000) == 1


def test_cumulative() -> None:
    c = cumulative(np.array([1, 0, 3]))
    np.testing.assert_allclose(c, [0.25, 0.25, 1.0])
    np.testing.assert_array_equal(cumulative(np.zeros(4, int)), np.zeros(4))


def test_bad_input() -> None:
    with pytest.raises(ParameterError, match="above max_level"):
        histogram(np.full((4, 4), 300, np.uint16), 255)
    with pytest.raises(ParameterError, match="integer levels"):
        histogram(np.zeros((4, 4), np.float32), 255)
    with pytest.raises(ParameterError, match=r"\(H, W\)"):
        histogram(np.zeros((4, 4, 3), np.uint16), 255)
    with pytest.raises(ParameterError, match="negative"):
        histogram(np.full((4, 4), -1, np.int32), 255)
    with pytest.raises(ParameterError, match="mask shape"):
        histograms(np.zeros((4, 4, 3), np.uint16), 255, np.zeros((3, 3), bool))


@pytest.mark.parametrize("dtype", [np.uint8, np.uint16])
@pytest.mark.parametrize("stride", [1, 3])
def test_compiled_counts_equal_bincount(dtype, stride) -> None:
    # the compiled one-pass counts (every channel at once, in place) against np.bincount of the
    # masked, strided copy they replaced
    rng = np.random.default_rng(7)
    top = 255 if dtype == np.uint8 else 4095
    frame = rng.integers(0, top + 1, (37, 53, 3)).astype(dtype)
    frame[5:9, 10:20] = top // 2  # runs of one level, as real images have
    mask = rng.random((37, 53)) < 0.6
    for m in (None, mask):
        want = np.stack(
            [
                np.bincount(
                    (
                        frame[..., c][::stride, ::stride][m[::stride, ::stride]]
                        if m is not None
                        else frame[..., c][::stride, ::stride].ravel()
                    ),
                    minlength=top + 1,
                )
                for c in range(3)
            ]
        )
        assert np.array_equal(histograms(frame, top, m, stride=stride), want)
        for c in range(3):
            assert np.array_equal(histogram(frame[..., c], top, m, stride=stride), want[c])


def test_compiled_counts_refuse_levels_above_max_only_where_counted() -> None:
    frame = np.full((4, 5, 3), 10, np.uint16)
    frame[1, 2, 0] = 300
    with pytest.raises(ParameterError, match="above max_level.*300"):
        histograms(frame, 255)
    with pytest.raises(ParameterError, match="above max_level.*300"):
        histogram(frame[..., 0], 255)
    mask = np.ones((4, 5), bool)
    mask[1, 2] = False  # the pixel is not counted: no error
    assert histograms(frame, 255, mask)[0, 10] == 19

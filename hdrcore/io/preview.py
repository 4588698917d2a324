"""PNG output of previews, masks and plots (8-bit or 16-bit), written atomically."""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np

from ..errors import ParameterError
from .atomic import atomic_write

__all__ = ["write_png", "encode_png"]


def _as_image(image: np.ndarray) -> np.ndarray:
    arr = np.asarray(image)
    if arr.ndim == 3 and arr.shape[2] == 1:
        arr = arr[..., 0]
    if arr.ndim not in (2, 3) or (arr.ndim == 3 and arr.shape[2] not in (3, 4)):
        raise ParameterError(
            "PNG image must be (H, W), (H, W, 3) or (H, W, 4)", found=str(arr.shape)
        )
    if arr.dtype not in (np.uint8, np.uint16):
        raise ParameterError("PNG image must be uint8 or uint16", found=str(arr.dtype))
    return np.ascontiguousarray(arr)


def encode_png(image: np.ndarray) -> bytes:
    """PNG bytes of an 8- or 16-bit grey, RGB or RGBA image."""
    import imagecodecs

    arr = _as_image(image)
    # zlib level 1: a 1.5-megapixel tonemapped photograph encoded in 0.15 s instead of 0.41 s
    # (level 6) for a file 1.5 % larger (photographic noise barely compresses).
    return bytes(imagecodecs.png_encode(arr, level=1))


def write_png(
    path: str | os.PathLike,
    image: np.ndarray,
    *,
    force: bool = False,
    inputs: Iterable[str | os.PathLike] = (),
) -> Path:
    """Write ``image`` as PNG atomically (refuses an existing file unless ``force``)."""
    data = encode_png(image)
    return atomic_write(path, lambda tmp: tmp.write_bytes(data), force=force, inputs=inputs)

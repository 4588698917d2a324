"""Helpers that write small test images with chosen EXIF."""

from __future__ import annotations

from fractions import Fraction
from pathlib import Path

import numpy as np
from PIL import Image
from PIL.TiffImagePlugin import IFDRational


def gradient(h: int = 24, w: int = 32, scale: float = 1.0, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    y, x = np.mgrid[0:h, 0:w]
    base = (x * 5 + y * 3).astype(float) * scale + rng.uniform(0, 10, (h, w))
    rgb = np.stack([base, base * 0.8, base * 0.6], -1)
    return np.clip(rgb, 0, 255).astype(np.uint8)


def write_jpeg(
    path: Path,
    rgb: np.ndarray,
    *,
    exposure: Fraction | None = None,
    f_number: float | None = None,
    iso: int | None = None,
    orientation: int | None = None,
    make: str | None = None,
    model: str | None = None,
    fmt: str = "JPEG",
) -> Path:
    im = Image.fromarray(rgb)
    exif = Image.Exif()
    if orientation is not None:
        exif[0x0112] = orientation
    if make is not None:
        exif[0x010F] = make
    if model is not None:
        exif[0x0110] = model
    ifd = exif.get_ifd(0x8769)
    if exposure is not None:
        ifd[0x829A] = IFDRational(exposure.numerator, exposure.denominator)
    if f_number is not None:
        ifd[0x829D] = IFDRational(Fraction(f_number).limit_denominator(100))
    if iso is not None:
        ifd[0x8827] = iso
    kwargs = {"exif": exif} if len(exif) or len(ifd) else {}
    if fmt == "JPEG":
        kwargs["quality"] = 95
    im.save(path, fmt, **kwargs)
    return path

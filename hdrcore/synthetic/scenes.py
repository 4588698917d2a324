"""Procedural radiance maps with several decades of dynamic range.

The scenes are made by the project itself (no third-party imagery), so the demo bracket in
``assets/`` can be redistributed. Each scene returns linear scene radiance, float32, shape
``(H, W, 3)``, strictly positive, with texture everywhere (registration and the histogram methods
need structure in every brightness range) and a dynamic range of at least four decades.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from scipy import ndimage

from ..errors import ParameterError, validate_method

__all__ = ["SCENES", "make_scene", "fractal_noise"]


def fractal_noise(
    shape: tuple[int, int], rng: np.random.Generator, *, octaves: int = 6, base_scale: float = 0.5
) -> np.ndarray:
    """Zero-mean, unit-variance fractal (1/f-like) noise of ``shape``, float32.

    Sums Gaussian-filtered white noise at octave scales; coarse octaves carry more energy.
    """
    h, w = shape
    out = np.zeros(shape, np.float32)
    for octave in range(octaves):
        sigma = base_scale * 2.0**octave
        layer = ndimage.gaussian_filter(rng.standard_normal(shape).astype(np.float32), sigma)
        std = float(layer.std()) or 1.0
        out += (layer / std) * (0.65 ** (octaves - 1 - octave))
    out -= out.mean()
    out /= float(out.std()) or 1.0
    return out


def _grid(shape: tuple[int, int]) -> tuple[np.ndarray, np.ndarray]:
    h, w = shape
    y, x = np.mgrid[0:h, 0:w].astype(np.float32)
    return x / max(w - 1, 1), y / max(h - 1, 1)


def _blob(
    x: np.ndarray, y: np.ndarray, cx: float, cy: float, r: float, aspect: float
) -> np.ndarray:
    d2 = ((x - cx) * aspect) ** 2 + (y - cy) ** 2
    return np.exp(-d2 / (2 * r * r)).astype(np.float32)


def _window_scene(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A dim textured room, a bright window onto a sunny textured exterior, and a lamp."""
    h, w = shape
    x, y = _grid(shape)
    aspect = w / h
    tex = fractal_noise(shape, rng)
    fine = fractal_noise(shape, rng, octaves=3, base_scale=0.7)
    wall = 0.03 * np.exp(0.8 * tex + 0.25 * fine) * (0.6 + 0.8 * y)
    rgb = np.stack([wall * 1.1, wall * 0.95, wall * 0.75], axis=-1)
    # The window: outdoor radiance ~ 300x the room, sky gradient above, foliage below.
    win = (x > 0.55) & (x < 0.9) & (y > 0.12) & (y < 0.62)
    sky = 8.0 * np.exp(0.35 * fine) * (1.2 - 0.6 * (y - 0.12) / 0.5)
    foliage = 2.5 * np.exp(0.9 * tex + 0.4 * fine)
    outdoor = np.where(y < 0.4, sky, foliage)
    out_rgb = np.stack(
        [
            outdoor * np.where(y < 0.4, 0.75, 0.8),
            outdoor * np.where(y < 0.4, 0.9, 1.0),
            outdoor * np.where(y < 0.4, 1.25, 0.55),
        ],
        axis=-1,
    )
    # Window frame bars.
    bars = (np.abs(x - 0.725) < 0.008) | (np.abs(y - 0.37) < 0.01)
    win_mask = win & ~bars
    rgb = np.where(win_mask[..., None], out_rgb, rgb)
    # A lamp: a small very bright source with a glow.
    lamp = _blob(x, y, 0.22, 0.3, 0.012, aspect)
    glow = _blob(x, y, 0.22, 0.3, 0.08, aspect)
    rgb += (400.0 * lamp + 0.6 * glow)[..., None] * np.array([1.0, 0.85, 0.55], np.float32)
    # A dark shadowed corner with texture (the low end of the range).
    corner = np.clip((0.35 - x) / 0.35, 0, 1) * np.clip((y - 0.7) / 0.3, 0, 1)
    rgb *= (1.0 - 0.9 * corner)[..., None]
    return rgb.astype(np.float32)


def _landscape_scene(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Backlit landscape: bright sky with the sun, textured hills in shadow."""
    h, w = shape
    x, y = _grid(shape)
    aspect = w / h
    tex = fractal_noise(shape, rng)
    fine = fractal_noise(shape, rng, octaves=3, base_scale=0.7)
    ridge = (
        0.45
        + 0.08 * np.sin(6.0 * x + 1.0)
        + 0.05
        * ndimage.gaussian_filter1d(rng.standard_normal(w).astype(np.float32), 8)[None, :]
        * 3
    )
    sky = np.exp(0.25 * fine) * (3.0 + 6.0 * (1 - y))
    ground = 0.02 * np.exp(1.0 * tex + 0.3 * fine) * (0.5 + y)
    is_sky = y < ridge
    rgb = np.where(
        is_sky[..., None],
        np.stack([sky * 0.8, sky * 0.95, sky * 1.3], -1),
        np.stack([ground * 0.8, ground * 1.0, ground * 0.6], -1),
    )
    sun = _blob(x, y, 0.7, 0.25, 0.015, aspect)
    halo = _blob(x, y, 0.7, 0.25, 0.1, aspect)
    rgb += (3000.0 * sun + 20.0 * halo)[..., None] * np.array([1.0, 0.95, 0.8], np.float32)
    return rgb.astype(np.float32)


def _night_scene(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """A night street: dark textured facades, lit windows of different brightness, street lamps."""
    h, w = shape
    x, y = _grid(shape)
    aspect = w / h
    tex = fractal_noise(shape, rng)
    base = 0.01 * np.exp(1.1 * tex) * (0.3 + y)
    rgb = np.stack([base * 0.9, base * 0.9, base * 1.2], -1)
    n_windows = 14
    for _ in range(n_windows):
        cx, cy = rng.uniform(0.05, 0.95), rng.uniform(0.1, 0.7)
        ww, hh = rng.uniform(0.02, 0.06), rng.uniform(0.03, 0.08)
        level = 10 ** rng.uniform(-0.5, 1.5)
        m = (np.abs(x - cx) < ww / 2) & (np.abs(y - cy) < hh / 2)
        tint = np.array([1.0, rng.uniform(0.7, 0.95), rng.uniform(0.4, 0.8)], np.float32)
        rgb = np.where(m[..., None], level * np.exp(0.3 * tex)[..., None] * tint, rgb)
    for cx in (0.15, 0.5, 0.85):
        lamp = _blob(x, y, cx, 0.55, 0.01, aspect)
        glow = _blob(x, y, cx, 0.6, 0.06, aspect)
        rgb += (800.0 * lamp + 0.5 * glow)[..., None] * np.array([1.0, 0.75, 0.4], np.float32)
    return rgb.astype(np.float32)


def _patches_scene(shape: tuple[int, int], rng: np.random.Generator) -> np.ndarray:
    """Textured patches spanning five decades in even log steps: a test chart for ratios."""
    h, w = shape
    x, y = _grid(shape)
    tex = fractal_noise(shape, rng, octaves=4)
    cols, rows = 8, 5
    idx = np.minimum((x * cols).astype(int), cols - 1) + cols * np.minimum(
        (y * rows).astype(int), rows - 1
    )
    log_levels = np.linspace(-2.5, 2.5, cols * rows)
    rng.shuffle(log_levels)
    lum = 10.0 ** log_levels[idx] * np.exp(0.4 * tex)
    hue = rng.uniform(0.6, 1.3, size=(cols * rows, 3)).astype(np.float32)
    return (lum[..., None] * hue[idx]).astype(np.float32)


SCENES: dict[str, Callable[[tuple[int, int], np.random.Generator], np.ndarray]] = {
    "window": _window_scene,
    "landscape": _landscape_scene,
    "night": _night_scene,
    "patches": _patches_scene,
}


def make_scene(
    name: str = "window", shape: tuple[int, int] = (256, 384), seed: int = 0
) -> np.ndarray:
    """Radiance map of the named procedural scene, float32 ``(H, W, 3)``, median 1.

    ``name`` is one of :data:`SCENES`; the same ``seed`` gives the same scene.
    """
    key = validate_method(name, SCENES, "scene")
    h, w = int(shape[0]), int(shape[1])
    if h < 16 or w < 16:
        raise ParameterError("scene too small", expected="at least 16x16 pixels", found=f"{h}x{w}")
    rng = np.random.default_rng(seed)
    radiance = SCENES[key]((h, w), rng)
    radiance = np.maximum(radiance, 1e-6)
    radiance /= float(np.median(radiance))
    return radiance.astype(np.float32)

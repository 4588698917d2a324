"""Small synthetic brackets on disk for the inspector's tests (PNG frames + exposure_times.txt)."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hdrcore.io import write_png
from hdrcore.synthetic import simulate_bracket

DEMO_DIR = Path(__file__).resolve().parents[2] / "assets" / "demo"


def write_png_bracket(
    folder: Path,
    *,
    shape: tuple[int, int] = (128, 192),
    times: tuple[float, ...] = (1.0, 4.0, 16.0),
    max_shift: float = 3.0,
    max_rotation_deg: float = 0.5,
    seed: int = 3,
) -> list[Path]:
    """A hand-held 8-bit gamma bracket written as PNG files, darkest first."""
    folder.mkdir(parents=True, exist_ok=True)
    sim = simulate_bracket(
        scene="window",
        shape=shape,
        exposure_times=times,
        bits=8,
        response="gamma",
        noise_sigma=1.0,
        max_shift=max_shift,
        max_rotation_deg=max_rotation_deg,
        seed=seed,
    )
    paths = []
    lines = []
    for k, (frame, t) in enumerate(zip(sim.frames, sim.exposure_times, strict=True)):
        p = folder / f"frame{k}.png"
        write_png(p, frame.astype(np.uint8), force=True)
        paths.append(p)
        lines.append(f"{p.name} {t:g}")
    (folder / "exposure_times.txt").write_text("\n".join(lines) + "\n")
    return paths

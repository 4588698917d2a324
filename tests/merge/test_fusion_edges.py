"""Exposure fusion at the edges of a hand-held bracket: where a warped frame does not reach,
the preview must not darken or draw a line (issue 15, the Pixel 7's preview edges)."""

from __future__ import annotations

import numpy as np

from hdrcore.merge.fusion import exposure_fusion


def _frames() -> list[np.ndarray]:
    """Three frames of a flat grey scene rendered alike (a phone's locally tone-mapped frames
    look alike), with a little noise (8 bits): every shift of
    a frame leaves its content as it was."""
    rng = np.random.default_rng(1)
    out = []
    for level in (115.0, 125.0, 135.0):
        noisy = level + rng.normal(0.0, 1.0, (120, 160, 3))
        out.append(np.clip(np.rint(noisy), 0, 255).astype(np.uint8))
    return out


def test_a_frame_that_does_not_reach_the_edge_leaves_no_band() -> None:
    frames = _frames()
    every = exposure_fusion(frames, max_level=255).mean(-1).astype(float)
    two = exposure_fusion(frames[:2], max_level=255).mean(-1).astype(float)
    # frame 2 reaches the reference through a 7 px vertical, 5 px horizontal shift: it covers
    # all but a 7 px strip at the top and a 5 px strip at the left
    to_ref = [np.eye(3), np.eye(3), np.array([[1.0, 0, 5.0], [0, 1.0, 7.0], [0, 0, 1.0]])]
    out = exposure_fusion(frames, max_level=255, to_reference=to_ref).mean(-1).astype(float)
    # rows (over the columns frame 2 covers) and columns (over the rows it covers), as means:
    # where frame 2 is missing, the other two frames' fusion; far inside, all three's; between,
    # a ramp from one to the other, no darker or brighter line (pixel noise averages out)
    for axis, edge in ((1, 7), (0, 5)):
        sel = (slice(None), slice(20, None)) if axis == 1 else (slice(20, None), slice(None))
        o, t, e = (a[sel].mean(axis=axis) for a in (out, two, every))
        assert np.abs(o[:edge] / t[:edge] - 1).max() < 0.015
        assert np.abs(o[edge + 15 :] / e[edge + 15 :] - 1).max() < 0.01
        assert np.all((o >= np.minimum(t, e) * 0.99) & (o <= np.maximum(t, e) * 1.01))

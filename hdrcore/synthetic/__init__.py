"""Brackets with known ground truth: procedural scenes, the seed's camera model, DNG output."""

from .camera import (
    RESPONSES,
    SimulatedBracket,
    apply_response,
    compose,
    invert,
    pair_matrix,
    rigid_matrix,
    simulate_bracket,
)
from .scenes import SCENES, fractal_noise, make_scene

__all__ = [
    "RESPONSES",
    "SCENES",
    "SimulatedBracket",
    "apply_response",
    "compose",
    "fractal_noise",
    "invert",
    "make_scene",
    "pair_matrix",
    "rigid_matrix",
    "simulate_bracket",
]

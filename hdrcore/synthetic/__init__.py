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
from .dng import (
    CFA_PATTERNS,
    default_black_level,
    encode_dng,
    linear_to_raw,
    mosaic,
    write_dng,
)
from .scenes import SCENES, fractal_noise, make_scene
from .writer import FORMATS, WrittenBracket, write_bracket

__all__ = [
    "CFA_PATTERNS",
    "FORMATS",
    "RESPONSES",
    "SCENES",
    "SimulatedBracket",
    "WrittenBracket",
    "apply_response",
    "compose",
    "default_black_level",
    "encode_dng",
    "fractal_noise",
    "invert",
    "linear_to_raw",
    "make_scene",
    "mosaic",
    "pair_matrix",
    "rigid_matrix",
    "simulate_bracket",
    "write_bracket",
    "write_dng",
]

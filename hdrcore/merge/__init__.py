"""The HDR merge: weighting functions, the weighted average, per-pixel maps and colour.

Public surface::

    from hdrcore.merge import merge, MergeResult, NoiseModel, WEIGHTS, camera_to_working
    from hdrcore.merge import colour_conversion  # merge(..., colour=...)
"""

from ._fused import warm_up
from .colour import (
    WORKING_SPACES,
    ColourConversion,
    apply_colour,
    camera_to_working,
    camera_to_working_matrix,
    colour_conversion,
)
from .consistency import GhostRegions, GhostTestParams, consistency_regions
from .maps import (
    DEFAULT_GHOST_THRESHOLD,
    DEFAULT_MODEL_ERROR,
    dominant_frame,
    ghost_score_from_moments,
    mean_shares,
    provenance_summary,
)
from .merge import (
    DEFAULT_CHUNK_PIXELS,
    DEFAULT_SATURATION,
    GHOST_TESTS,
    MERGE_ENGINES,
    RESAMPLING,
    MergeResult,
    default_engine,
    merge,
)
from .weights import WEIGHTS, NoiseModel, WeightFunction, Weighting, weights

__all__ = [
    "DEFAULT_CHUNK_PIXELS",
    "DEFAULT_GHOST_THRESHOLD",
    "DEFAULT_MODEL_ERROR",
    "DEFAULT_SATURATION",
    "GHOST_TESTS",
    "MERGE_ENGINES",
    "RESAMPLING",
    "WEIGHTS",
    "WORKING_SPACES",
    "ColourConversion",
    "GhostRegions",
    "GhostTestParams",
    "MergeResult",
    "NoiseModel",
    "WeightFunction",
    "Weighting",
    "apply_colour",
    "camera_to_working",
    "camera_to_working_matrix",
    "colour_conversion",
    "consistency_regions",
    "default_engine",
    "dominant_frame",
    "ghost_score_from_moments",
    "mean_shares",
    "merge",
    "provenance_summary",
    "warm_up",
    "weights",
]

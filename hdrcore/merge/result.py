"""The result of :func:`hdrcore.merge.merge`: the radiance map and how each pixel was made."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from .consistency import GhostRegions
from .maps import dominant_frame, provenance_summary
from .weights import NoiseModel

__all__ = ["MergeResult"]


@dataclass(frozen=True, eq=False)
class MergeResult:
    """The merged radiance map and the per-pixel diagnostics of how it was made.

    radiance
        float32 ``(H, W, C)``, ``g(M) / dt`` in the units of the exposure times given.
    weight_sum
        float32 ``(H, W)``: the total weight (all frames, all channels) behind each pixel; 0 where
        a fallback value was used.
    shares
        float16 ``(N, H, W)``: frame ``k``'s share of the weight at each pixel, in the order the
        frames were given; sums to 1 over ``k`` at every pixel.
    weight_sum_map, share_maps, clip_count_map
        ``weight_sum``, ``shares`` and ``clip_count`` as stored: ``None`` from
        ``merge(..., weight_maps=False)``, and then reading the property raises
        ``ValueError`` (``provenance`` holds the shares' summary).
    clip_count
        uint8 ``(H, W)``: number of valid frames in which the pixel is clipped (any channel).
    clipped
        bool ``(H, W)``: clipped in every valid frame that could see the pixel (frames below
        the noise floor that are shorter exposures, e.g. a black frame, do not count); the value
        is the darkest clipped frame's (a lower bound).
    underexposed
        bool ``(H, W)``: some channel is at or below the noise floor in every usable frame.
    ghost_score, ghost
        float16 ``(H, W)`` per-pixel score of :func:`hdrcore.merge.maps.ghost_score_from_moments`
        and the ghost mask: with ``ghost_test="pixels"`` ``ghost_score > ghost_threshold``, with
        ``"regions"`` (the default) the pixels of the regions where blocks of the frames
        disagree (:func:`hdrcore.merge.consistency.consistency_regions`, in ``ghost_regions``).
    engine
        which implementation ran: ``"numba"``, the compiled kernel, the only one (a key of
        :data:`MERGE_ENGINES`; results of earlier releases may say ``"numpy"``).
    deghosted
        bool ``(H, W)``: pixels filled from one frame by ``merge(..., deghost=True)`` (``None``
        without it).
    provenance
        the shares' summary (:func:`hdrcore.merge.maps.provenance_summary`) counted by the
        kernel when the shares are not kept; ``None`` when they are (it is read from them).
    """

    radiance: np.ndarray
    weight_sum_map: np.ndarray | None  # ``weight_sum``, or None: not kept
    share_maps: np.ndarray | None  # ``shares``, or None: not kept
    clip_count_map: np.ndarray | None  # ``clip_count``, or None: not kept
    clipped: np.ndarray
    underexposed: np.ndarray
    ghost_score: np.ndarray
    ghost: np.ndarray
    exposure_times: tuple[float, ...]
    weighting: str
    units: str
    max_level: int | None
    saturation_level: tuple[float, ...]
    noise_floor: float
    noise: NoiseModel
    ghost_threshold: float
    model_error: float
    status: str
    message: str
    timings: dict[str, float] = field(default_factory=dict)
    engine: str = "numba"
    deghosted: np.ndarray | None = None
    ghost_test: str = "pixels"
    ghost_regions: GhostRegions | None = None
    provenance: dict[str, list[float]] | None = None
    pending_ghost_test: Callable[[], MergeResult] | None = field(
        default=None, repr=False, compare=False
    )

    @property
    def ghost_test_pending(self) -> bool:
        """The region ghost test was left for later (``merge(..., defer_ghost_test=True)``):
        ``ghost`` is empty and ``ghost_regions`` None until :meth:`with_ghost_test`."""
        return self.pending_ghost_test is not None

    def with_ghost_test(self) -> MergeResult:
        """This result with its region ghost test done (itself when none is pending). The test
        runs once, whoever asks first; later calls return the same result."""
        if self.pending_ghost_test is None:
            return self
        return self.pending_ghost_test()

    @property
    def weight_sum(self) -> np.ndarray:
        if self.weight_sum_map is None:
            raise ValueError("the merge kept no weight sum (merge(..., weight_maps=False))")
        return self.weight_sum_map

    @property
    def shares(self) -> np.ndarray:
        if self.share_maps is None:
            raise ValueError("the merge kept no shares (merge(..., weight_maps=False))")
        return self.share_maps

    @property
    def clip_count(self) -> np.ndarray:
        if self.clip_count_map is None:
            raise ValueError("the merge kept no clip count (merge(..., weight_maps=False))")
        return self.clip_count_map

    @property
    def n_frames(self) -> int:
        return len(self.exposure_times)

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.radiance.shape[0]), int(self.radiance.shape[1]))

    @property
    def dominant_frame(self) -> np.ndarray:
        """Index of the frame with the largest share at each pixel, uint8 ``(H, W)``."""
        return dominant_frame(self.shares)

    def provenance_summary(self) -> dict[str, list[float]]:
        """Each frame's mean share and the fraction of pixels it dominates
        (:func:`hdrcore.merge.maps.provenance_summary`), from the shares or, when they were
        not kept, from the kernel's count."""
        if self.share_maps is not None:
            return provenance_summary(self.share_maps)
        if self.provenance is None:
            raise ValueError("the merge kept neither its shares nor their summary")
        return self.provenance

    @property
    def success(self) -> bool:
        return self.status in ("ok", "warning")

    @property
    def clipped_fraction(self) -> float:
        """Share of the pixels saturated in every frame."""
        return _fraction(self.clipped)

    @property
    def underexposed_fraction(self) -> float:
        """Share of the pixels under the noise floor in every frame."""
        return _fraction(self.underexposed)

    @property
    def ghost_fraction(self) -> float:
        """Share of the pixels the ghost test flagged."""
        return _fraction(self.ghost)

    @property
    def deghosted_fraction(self) -> float | None:
        """Share of the pixels deghost filled from one frame (``None`` without deghost)."""
        return None if self.deghosted is None else _fraction(self.deghosted)

    def summary(self) -> dict:
        """JSON-ready diagnostics (no arrays)."""
        return {
            "status": self.status,
            "message": self.message,
            "shape": list(self.shape),
            "n_frames": self.n_frames,
            "exposure_times": list(self.exposure_times),
            "weighting": self.weighting,
            "units": self.units,
            "max_level": self.max_level,
            "saturation_level": list(self.saturation_level),
            "noise_floor": self.noise_floor,
            "noise": self.noise.to_json(),
            "ghost_threshold": self.ghost_threshold,
            "model_error": self.model_error,
            "clipped_fraction": self.clipped_fraction,
            "underexposed_fraction": self.underexposed_fraction,
            "ghost_test": self.ghost_test,
            "ghost_fraction": self.ghost_fraction,
            "ghost_regions": None if self.ghost_regions is None else self.ghost_regions.to_json(),
            "deghosted_fraction": self.deghosted_fraction,
            "provenance": self.provenance_summary(),
            "timings": dict(self.timings),
            "engine": self.engine,
        }


def _fraction(mask: np.ndarray) -> float:
    """The share of True pixels (a count: a 24 MP mask's ``mean`` converts it to floats, 30-50
    ms)."""
    return float(np.count_nonzero(mask)) / mask.size if mask.size else 0.0

"""Merge before demosaicing: the RAW frames of a tripod bracket merged per CFA site, then one
demosaic.

The per-frame path demosaics every frame (three demosaics for three frames) and merges the RGB
frames; each demosaiced pixel mixes its neighbours' sensor values, so a frame's weight at a
pixel speaks for values it did not measure, and a demosaic that is not linear in the exposure
(LibRaw's AHD) gives each frame a slightly different colour. Here the four sites of each 2x2
cell are the channels of a half-size frame (:func:`hdrcore.exposure.registered.cfa_planes`:
black-subtracted, held at ``max_level``), the frames are merged with the project's merge
(:func:`hdrcore.merge.merge`, its compiled kernel with 4 channels: the noise-aware weights of
the noise model, a frame dropped in a cell where any of its sites is clipped, the ghost maps),
the merged cells are put back in their places as one float mosaic of radiance, and that mosaic
is demosaiced once (:func:`hdrcore.demosaic.demosaic`). The merged mosaic is also what a CFA
float DNG stores (:mod:`hdrcore.io.dng`).

Tripod brackets only (no transforms): a hand-held frame would need its motion applied per
colour plane with each site's sub-pixel phase, which is not built.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from ..demosaic import bayer_channels, demosaic
from ..errors import ParameterError
from ..exposure.registered import cfa_planes
from ..io.frame import RawCFA, apply_orientation
from .merge import MergeResult, merge
from .weights import NoiseModel

__all__ = ["MosaicMerge", "interleave_sites", "merge_mosaic", "site_ceiling"]


@dataclass(frozen=True, eq=False)
class MosaicMerge:
    """The merged mosaic and its demosaic.

    ``mosaic``: float32 ``(H, W)`` (even ``H, W``: the sensor's, an odd last row or column
    left out), each site's merged linear value per unit of exposure time (``g(M) / dt``), in
    sensor orientation; ``channels`` its 2x2 colours (0 R, 1 G, 2 B); ``rgb``: float32 ``(H,
    W, 3)`` camera RGB, demosaiced and turned upright by ``orientation``; ``merge``: the
    half-size merge of the sites (its maps are per 2x2 cell) of a tripod bracket;
    ``site_merges``: with ``transforms``, the four merges of the sites (row-major), ``merge``
    then ``None``.
    """

    mosaic: np.ndarray
    channels: np.ndarray
    rgb: np.ndarray
    merge: MergeResult | None
    orientation: int | None
    site_merges: tuple[MergeResult, ...] = ()


def interleave_sites(planes: np.ndarray) -> np.ndarray:
    """``(h, w, 4)`` site planes (site ``(r, c)`` in channel ``2 r + c``) -> ``(2h, 2w)``."""
    p = np.asarray(planes)
    if p.ndim != 3 or p.shape[2] != 4:
        raise ParameterError("site planes must be (h, w, 4)", found=str(p.shape))
    h, w = p.shape[:2]
    out = np.empty((2 * h, 2 * w), p.dtype)
    for r in range(2):
        for c in range(2):
            out[r::2, c::2] = p[..., 2 * r + c]
    return out


def site_ceiling(
    planes: Sequence[np.ndarray],
    exposure_times: Sequence[float],
    max_level: int,
    saturation_level: float | None = None,
) -> np.ndarray:
    """Per site, the clipping level (per unit time, ``saturation / max_level / t``) of the
    longest frame in which the site itself is unclipped (the darkest frame's where it is
    clipped in all). float32, the shape of one frame's site planes.

    The merge drops a frame from a whole cell where any site is clipped, so a site's merged
    value can come from a darker frame than this; :func:`merge_mosaic` therefore holds the
    ceiling at least at the site's merged value."""
    sat = 0.98 * max_level if saturation_level is None else float(saturation_level)
    order = np.argsort(np.asarray(exposure_times, np.float64))
    out = np.full(
        planes[0].shape, np.float32(sat / max_level / exposure_times[order[0]]), np.float32
    )
    for k in order[1:]:
        level = np.float32(sat / max_level / exposure_times[k])
        np.copyto(out, level, where=planes[k] < sat)
    return out


def merge_mosaic(
    cfas: Sequence[RawCFA],
    exposure_times: Sequence[float],
    *,
    max_level: int,
    saturation_level: float | None = None,
    noise_floor: float | None = None,
    noise: NoiseModel | None = None,
    method: str = "malvar2004",
    orientation: int | None = None,
    workers: int | None = None,
    hdr_edges: bool = True,
    transforms: Sequence[np.ndarray | None] | None = None,
) -> MosaicMerge:
    """Merge the CFA data of a tripod RAW bracket per site, then demosaic once.

    ``cfas``: the frames' :class:`~hdrcore.io.frame.RawCFA` (one pattern for all);
    ``exposure_times``, ``saturation_level``, ``noise_floor``, ``noise`` as for
    :func:`hdrcore.merge.merge` (levels after black subtraction, ``max_level`` the bracket's);
    ``method`` the demosaic (:data:`hdrcore.demosaic.DEMOSAIC_METHODS`); ``orientation`` the EXIF
    value the RGB result is turned by (the frames' levels are upright, their CFA data not).
    ``hdr_edges``: the demosaic reads each pixel's neighbours held at the pixel's
    :func:`site_ceiling` (without it, a pixel beside a region far brighter than itself takes
    the merged contrast through the filter's taps: on a simulated window scene, up to 17x the
    pixel's value next to a window clipped in every frame, where the per-frame path, whose
    frames clip that region, errs by up to 2x).

    ``transforms`` (hand-held): per frame ``None`` or the 2x3 / 3x3 matrix taking reference
    pixel coordinates to that frame's (as :func:`hdrcore.merge.merge` takes them), in the
    sensor's orientation (``orientation`` None or 1). Each site is then merged on its own
    plane, every frame read there through the matrix moved to that site's sub-pixel phase:
    plane pixel ``u`` of site ``(r, c)`` is sensor pixel ``S u = 2 u + (c, r)``, so the
    plane's matrix is ``S^-1 A S``; a frame is dropped per site (not per cell) where it clips,
    and the ceiling is the clipping level of the longest frame the site's merge used.
    """
    if len(cfas) < 2:
        raise ParameterError("a mosaic merge needs at least two frames", found=str(len(cfas)))
    first = cfas[0]
    for c in cfas[1:]:
        if (
            c.data.shape != first.data.shape
            or not np.array_equal(c.pattern, first.pattern)
            or c.colors != first.colors
        ):
            raise ParameterError(
                "the frames' CFA layouts differ",
                expected=f"{first.data.shape} {first.pattern.tolist()}",
                found=f"{c.data.shape} {np.asarray(c.pattern).tolist()}",
            )
    channels = bayer_channels(first.pattern, first.colors)
    planes = [cfa_planes(c.data, c.pattern, c.colors, c.black_level, max_level)[0] for c in cfas]
    common: dict[str, Any] = dict(
        max_level=max_level,
        saturation_level=saturation_level,
        noise_floor=noise_floor,
        weighting="noise-aware",
        noise=noise,
        workers=workers,
    )
    moved = transforms is not None and any(t is not None for t in transforms)
    res: MergeResult | None = None
    site_merges: tuple[MergeResult, ...] = ()
    if not moved:
        res = merge(planes, exposure_times, **common)
        mosaic = interleave_sites(res.radiance)
        ceiling = None
        if hdr_edges:
            ceiling = interleave_sites(
                site_ceiling(planes, exposure_times, max_level, saturation_level)
            )
    else:
        assert transforms is not None  # moved
        if orientation not in (None, 1):
            raise ParameterError(
                "a hand-held mosaic merge needs the sensor's orientation",
                expected="orientation 1",
                found=str(orientation),
            )
        if len(transforms) != len(cfas):
            raise ParameterError(
                "one transform per frame", expected=str(len(cfas)), found=str(len(transforms))
            )
        site_merges = tuple(
            merge(
                [np.ascontiguousarray(pl[..., 2 * r + c : 2 * r + c + 1]) for pl in planes],
                exposure_times,
                transforms=[_site_matrix(t, r, c) for t in transforms],
                **common,
            )
            for r in range(2)
            for c in range(2)
        )
        mosaic = interleave_sites(np.concatenate([m.radiance for m in site_merges], axis=2))
        ceiling = None
        if hdr_edges:
            ceiling = interleave_sites(
                np.stack(
                    [
                        _used_ceiling(m, exposure_times, max_level, saturation_level)
                        for m in site_merges
                    ],
                    axis=2,
                )
            )
    if ceiling is not None:
        np.maximum(ceiling, mosaic, out=ceiling)
    # The merged sites are already black-subtracted: one colour per site, black 0.
    pattern = np.array([[0, 1], [2, 3]])
    colors = "".join("RGB"[int(v)] for v in channels.ravel())
    rgb = demosaic(
        mosaic, pattern, colors, method=method, dtype=np.float32, workers=workers, ceiling=ceiling
    )
    return MosaicMerge(
        mosaic=mosaic,
        channels=channels,
        rgb=apply_orientation(rgb, orientation),
        merge=res,
        orientation=orientation,
        site_merges=site_merges,
    )


def _site_matrix(a: np.ndarray | None, r: int, c: int) -> np.ndarray | None:
    """``S^-1 A S`` for the plane of site ``(r, c)`` (``S u = 2 u + (c, r)``), 2x3 or 3x3 as
    given; ``None`` stays ``None``."""
    if a is None:
        return None
    m = np.asarray(a, np.float64)
    full = np.vstack([m, [0.0, 0.0, 1.0]]) if m.shape == (2, 3) else m
    if full.shape != (3, 3):
        raise ParameterError("a transform must be 2x3 or 3x3", found=str(m.shape))
    s = np.array([[2.0, 0.0, c], [0.0, 2.0, r], [0.0, 0.0, 1.0]])
    out = np.linalg.inv(s) @ full @ s
    return out[:2] if m.shape == (2, 3) else out


def _used_ceiling(
    res: MergeResult,
    exposure_times: Sequence[float],
    max_level: int,
    saturation_level: float | None,
) -> np.ndarray:
    """Per pixel of a site's merge, the clipping level (per unit time) of the longest frame
    with a share of its weight (the darkest frame's where none has): float32 ``(h, w)``."""
    sat = 0.98 * max_level if saturation_level is None else float(saturation_level)
    order = np.argsort(np.asarray(exposure_times, np.float64))
    out = np.full(
        res.radiance.shape[:2], np.float32(sat / max_level / exposure_times[order[0]]), np.float32
    )
    for k in order[1:]:
        np.copyto(out, np.float32(sat / max_level / exposure_times[k]), where=res.shares[k] > 0)
    return out

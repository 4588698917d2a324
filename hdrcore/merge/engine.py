"""How the merge's one kernel (:mod:`hdrcore.merge._fused`, compiled by numba) is called: its
typed argument groups, its per-level tables, the engine names :func:`hdrcore.merge.merge`
takes."""

from __future__ import annotations

import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor

import numpy as np

from ..errors import ParameterError, validate_method
from . import _fused
from .colour import ColourConversion
from .plan import IDENTITY, Outputs, Plan, SampleModel, levels_past_lut
from .weights import WEIGHTS

__all__ = [
    "MERGE_ENGINES",
    "default_engine",
    "kernel_engine",
    "level_tables",
    "provenance_from_counts",
    "run_fused",
]

MERGE_ENGINES: dict[str, str] = {
    "numba": "the one-pass merge kernel compiled by numba (hdrcore.merge._fused), any channel "
    "count",
}
"""Implementations of :func:`merge` by name: one. (``"numpy"``, the numpy engine, is gone; the
name is a deprecated alias of the kernel for one release, see :func:`kernel_engine`.)"""

DEPRECATED_ENGINES = ("numpy",)


def default_engine() -> str:
    """``"numba"``: the only implementation (kept for callers of earlier releases)."""
    return "numba"


def kernel_engine(engine: str | None) -> str:
    """The engine a ``merge(..., engine=...)`` runs: ``"numba"`` for ``None``, ``"numba"`` and
    the deprecated ``"numpy"`` (with a ``DeprecationWarning``); any other name and a missing
    numba are a :class:`ParameterError`."""
    if isinstance(engine, str) and engine.strip().lower() in DEPRECATED_ENGINES:
        warnings.warn(
            "merge(engine='numpy') is deprecated: the numpy merge engine was removed and the "
            "compiled kernel runs instead (same results); drop the argument",
            DeprecationWarning,
            stacklevel=3,
        )
        engine = None
    engine = "numba" if engine is None else validate_method(engine, MERGE_ENGINES, "merge engine")
    if not _fused.AVAILABLE:
        raise ParameterError(
            "the merge needs numba (a dependency of hdrcore)",
            expected="numba installed",
            found="numba not importable",
        )
    return engine


def _kernel_dtype(frames: tuple[np.ndarray, ...], integer: bool) -> tuple[np.ndarray, ...]:
    """The frames in a dtype the kernel is compiled for: float32, uint8 or uint16 (integer
    frames of mixed or other unsigned dtypes as uint16, levels above 65535 read as 65535; the
    plan keeps ``max_level`` within 65535)."""
    if not integer:
        return frames
    dtypes = {f.dtype for f in frames}
    if len(dtypes) == 1 and dtypes <= {np.dtype(np.uint8), np.dtype(np.uint16)}:
        return frames
    top = np.iinfo(np.uint16).max
    return tuple(
        (f if np.iinfo(f.dtype).max <= top else np.minimum(f, top)).astype(np.uint16)
        for f in frames
    )


def _one_type(arrays: Sequence[np.ndarray]) -> tuple[np.ndarray, ...]:
    """The arrays as one numba type: read-only views of all when any is read-only (a decoded
    bracket's levels are; a frame made by the caller is not), since the kernel indexes the
    tuple at run time and numba cannot index a tuple of mixed types."""
    if any(not a.flags.writeable for a in arrays) and any(a.flags.writeable for a in arrays):
        views = []
        for a in arrays:
            v = a.view()
            v.setflags(write=False)
            views.append(v)
        return tuple(views)
    return tuple(arrays)


def level_tables(p: Plan, m: SampleModel) -> np.ndarray:
    """float32 ``(N, C L, 4)``: ``E_k, w, w var(E_k)`` (and a zero: one aligned 16-byte line a
    level) of every level ``0..max_level`` (``L`` levels) of every frame, channel ``ch``'s
    level ``v`` at row ``ch L + v`` (the kernel's
    :func:`~hdrcore.merge._fused._accumulate_levels_table`, which makes ``w E_k`` and
    ``w E_k**2`` from the first two). The float32 operations are the kernel's own
    (:func:`~hdrcore.merge._fused._accumulate_run`), in its order, so an entry is bit for bit
    what the kernel computes for a sample of that level (the noise floor applied; clipping and
    masks, which depend on the pixel, not), ``exp`` of the Gaussian weight numpy's (the
    kernel's vectorised ``exp`` may differ in the last place)."""
    n, c = len(p.frames), p.shape[2]
    length = int(p.max_level or 0) + 1
    levels = np.arange(length, dtype=p.frames[0].dtype)
    level = np.multiply(levels, m.inv_max, dtype=np.float32)
    weight = WEIGHTS[p.weighting]
    tab = np.zeros((n, c * length, 4), np.float32)
    for ch in range(c):
        if p.lut is None or p.lut_var is None:
            x = level
            var_x = np.multiply(x, m.shot)
        else:
            x = p.lut[ch].take(levels.astype(np.intp))
            var_x = p.lut_var[ch].take(levels.astype(np.intp))
            if m.shot:
                var_x += np.multiply(x, m.shot)
        var_x += m.const_var
        for k in range(n):
            t = float(p.times[k])
            row = slice(ch * length, (ch + 1) * length)
            e = np.multiply(x, np.float32(1.0 / t))
            wk = weight(level, x, t, var_x)
            wk *= level > m.floor_norm
            tab[k, row, 0] = e
            tab[k, row, 1] = wk
            var = var_x * wk
            var *= np.float32(1.0 / (t * t))
            tab[k, row, 2] = var
    return tab


def run_fused(
    p: Plan,
    out: Outputs,
    m: SampleModel,
    spans: list[tuple[int, int]],
    workers: int,
    force_tables: bool = False,
    colour: ColourConversion | None = None,
) -> dict[str, list[float]] | None:
    """The kernel (:func:`hdrcore.merge._fused.merge_rows`) over ``spans`` of rows (on
    ``workers`` threads), ``colour`` applied inside it. Integer frames read in place go
    through per-level tables (:func:`level_tables`) when they have a LUT or
    ``force_tables``. Outputs without the shares and the weight sum (``None``): returns the
    provenance summary the kernel counted instead (:func:`provenance_from_counts`), else
    ``None``."""
    frames = _kernel_dtype(p.frames, p.integer)
    frames_t = _one_type(frames)
    dummy = np.ones((1, 1), bool)
    masks_t = _one_type([m if m is not None else dummy for m in p.masks])
    has_mask = np.array([m is not None for m in p.masks], np.bool_)
    order = np.ascontiguousarray(p.order, np.int64)
    sat = np.ascontiguousarray(p.saturation, np.float64)
    me2 = m.model_error2
    thr = m.ghost_threshold
    maps = out.shares is not None and out.weight_sum is not None and out.clip_count is not None
    n = len(p.frames)
    # without the maps: the provenance summary, counted per output row (_fused.FusedOutputs)
    rows = 1 if maps else p.shape[0]
    prov_count = np.zeros((rows, n), np.int64)
    prov_units = np.zeros((rows, n), np.int64)
    outs = (
        out.radiance,
        out.weight_sum if out.weight_sum is not None else np.empty((1, 1), np.float32),
        (out.shares if out.shares is not None else np.empty((1, 1, 1), np.float16)).view(np.uint16),
        out.clip_count if out.clip_count is not None else np.empty((1, 1), np.uint8),
        out.clipped,
        out.underexposed,
        out.ghost_score.view(np.uint16),
        out.ghost,
        maps,
        prov_count,
        prov_units,
    )
    inv_t = np.array([1.0 / t for t in p.times], np.float32)
    use_tab = bool(
        p.integer
        and (p.lut is not None or force_tables)
        and not all(tf is not None for tf in p.transforms)
    )
    c = p.shape[2]
    if use_tab:
        tabs = level_tables(p, m)
    else:
        tabs = np.zeros((len(frames), c, 4), np.float32)
    inv_t2 = np.array([1.0 / (t * t) for t in p.times], np.float32)
    t2 = np.array([float(t) ** 2 for t in p.times], np.float32)
    weighting = WEIGHTS[p.weighting]
    wcode = weighting.code  # built-ins: inlined in the kernel; others: a function pointer
    wfn = (weighting if wcode < 0 else WEIGHTS["uniform"]).pointer
    mats = np.zeros((len(frames), 3, 3))
    for k, tf in enumerate(p.transforms):
        mats[k] = IDENTITY if tf is None else tf
    has_mat = np.array([tf is not None for tf in p.transforms], np.bool_)
    # local refinement: the frames' displacement fields on one node grid
    fl = [f for f in p.fields if f is not None] if p.fields else []
    if fl:
        flds = np.zeros((len(frames),) + np.shape(fl[0].offsets), np.float64)
        for k, f in enumerate(p.fields):
            if f is not None:
                flds[k] = f.offsets
        fgeo = np.array([1.0 / fl[0].step, fl[0].origin[0], fl[0].origin[1]])
    else:
        flds = np.zeros((len(frames), 2, 2, 2))
        fgeo = np.array([1.0, 0.0, 0.0])
    has_fld = np.array(
        [bool(p.fields) and p.fields[k] is not None for k in range(len(frames))], np.bool_
    )
    has_lut = p.lut is not None and p.lut_var is not None
    lut = p.lut if p.lut is not None else np.zeros((c, 2), np.float32)
    lut_var = p.lut_var if p.lut_var is not None else lut
    hi = np.float32(p.max_level if p.integer else 1.0)
    # a tuple: its length, the channel count, is a constant of each compiled specialisation
    tap_thr = tuple(_fused.tap_thresholds(sat, frames_t[0].dtype))
    ntap = 4 if p.resample == "cubic" else 2
    # levels past the LUT (refused): only a frame that holds any is searched for them
    lmax = lut.shape[1] - 1
    oor = np.array(
        [
            bool(has_lut and has_mat[k] and np.iinfo(f.dtype).max > lmax and f.max() > lmax)
            for k, f in enumerate(frames_t)
        ],
        np.bool_,
    )

    flats = tuple(f.reshape(f.shape[0], -1) for f in frames_t)
    # padded to a multiple of TUPLE_SLOTS: one compiled kernel serves every frame count
    pad = -len(frames_t) % _fused.TUPLE_SLOTS
    frames_t += (frames_t[0],) * pad
    flats += (flats[0],) * pad
    masks_t += (masks_t[0],) * pad
    cm, cwb, cneu = colour if colour is not None else (np.eye(3), np.ones(3), np.ones(3))

    fr = _fused.FusedFrames(frames_t, flats, masks_t, has_mask, order, inv_t, inv_t2, t2)
    warp = _fused.FusedWarp(mats, has_mat, ntap, oor, flds, has_fld, fgeo, float(p.feather))
    model = _fused.FusedModel(
        wcode,
        m.shot,
        m.const_var,
        m.floor_norm,
        m.inv_max,
        hi,
        has_lut,
        lut,
        lut_var,
        tap_thr,
        use_tab,
        tabs,
    )
    fin = _fused.FusedFinish(me2, thr, colour is not None, cm, cwb, cneu)
    dst = _fused.FusedOutputs(*outs)

    def work(span: tuple[int, int]) -> int:
        return _fused.merge_rows(fr, warp, model, wfn, fin, dst, span[0], span[1])

    if workers == 1:
        bad_levels = sum(work(sp) for sp in spans)
    else:
        with ThreadPoolExecutor(max_workers=workers) as pool:
            bad_levels = sum(pool.map(work, spans))
    if bad_levels:
        raise levels_past_lut(p.max_level, f"{bad_levels} samples above {p.max_level}")
    if maps:
        return None
    return provenance_from_counts(prov_count.sum(axis=0), prov_units.sum(axis=0), p.shape[:2])


def provenance_from_counts(
    counts: np.ndarray, units: np.ndarray, shape: tuple[int, ...]
) -> dict[str, list[float]]:
    """:func:`hdrcore.merge.maps.provenance_summary` from the kernel's per-frame dominant
    pixel counts and share sums in units of 2**-24 (exact integers: the float64 sums of the
    float16 shares, which are exact in any order below 2**29 pixels, are these times
    2**-24)."""
    totals = np.asarray(units, np.int64).astype(np.float64) * 2.0**-24
    size = max(int(np.prod(shape)), 1)
    total = float(np.sum(totals))
    return {
        "mean_share": [float(v) for v in (totals / total if total > 0 else totals)],
        "dominant_fraction": [float(c) / size for c in counts],
    }

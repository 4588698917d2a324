"""The whole method as one cached pipeline: histograms -> response -> ratios -> registration ->
warp -> merge -> colour -> preview.

:class:`Pipeline` holds a loaded :class:`~hdrcore.io.Bracket` and runs the stages with
:class:`PipelineParams`. Each stage's result is cached with the parameters (and upstream results)
it depends on, so a new run re-computes only what a parameter change touches: moving the
saturation level re-fits the ratios from the cached histograms, then re-registers and re-merges;
changing the tonemap exposure only re-renders the preview. Every run returns one
:class:`PipelineResult` holding every stage's own result object (with its diagnostics), the
timings, the warnings and plain-language verdicts; :meth:`PipelineResult.to_report` gives the
JSON report of ``hdrcore merge --report`` with the field names of ``ratios --json`` and
``align --json``.

Units: the saturation level ``Z`` and the noise floor are in the frames' integer levels, as in the
paper (``None`` picks :func:`hdrcore.exposure.default_saturation` and
:meth:`Pipeline.auto_noise_floor`, 3 sigma of the noise measured from the frames,
:mod:`hdrcore.noise`); the registration threshold ``t`` is a fraction of the saturation level
(eq. 7).

Weak frames degrade the run, never fail it: a frame without signal (black, saturated;
:mod:`hdrcore.signal`) or without a ratio linking it to the rest (no overlap, no EXIF) is left out
of every stage, the result says which and why, and only a bracket with fewer than two usable
frames raises.
"""

from __future__ import annotations

import logging
import math
import threading
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass, field, replace
from dataclasses import fields as dataclass_fields
from functools import partial
from typing import Any

import numpy as np

from ._once import Once
from ._threads import set_workers, thread_map
from .diagnose import Verdict, diagnose
from .errors import EstimationError, ParameterError, validate_method
from .exposure import (
    DEFAULT_METHOD as DEFAULT_EXPOSURE_METHOD,
)
from .exposure import (
    EXPOSURE_METHODS,
    BracketExposureResult,
    BracketHistograms,
    bracket_exposures_from_histograms,
    bracket_histograms,
    default_noise_floor,
    default_saturation,
    srgb_lut,
)
from .exposure.chain import assemble_bracket
from .exposure.interval import judge
from .exposure.registered import bracket_exposures_from_pixels, cfa_planes
from .exposure.result import ExposureRatioResult
from .geometry import corner_error, nearest_in_frame, scale_matrix
from .io import Bracket
from .merge import DEFAULT_MODEL_ERROR, MergeResult, NoiseModel, merge
from .merge.colour import (
    ColourConversion,
    colour_conversion,
    convert_space_in_place,
    space_to_space_matrix,
)
from .merge.colour_check import ColourResult, FrameMeasures, check_colour, measure_frames
from .merge.fusion import METHOD as FUSION_METHOD
from .merge.fusion import exposure_fusion
from .noise import BracketNoise, FrameNoise, bracket_noise, frame_noise
from .registration import (
    MODELS,
    REGISTRATION_METHODS,
    BracketRegistration,
    PairRegistration,
    invert,
    register_bracket,
    register_pair,
    rigid_parameters,
    to_reference,
    warp_to_reference,
)
from .registration._memo import RunMemo
from .registration.residual import PATTERN_COMPONENTS
from .registration.thresholds import snap_levels
from .resample import bin_channel, downsample_area, downsample_factor
from .response import RESPONSE_METHODS, ResponseCurve, resolve_response
from .signal import FrameSignal, frame_signal
from .stage_graph import Inputs, Stage, StageCache, StageGraph
from .tonemap import TONEMAP_OPERATORS, TonemapResult, tonemap

__all__ = [
    "ALIGN_CHOICES",
    "LOCAL_CHOICES",
    "REFINE_CHOICES",
    "Cancelled",
    "colour_masks",
    "GRAPH",
    "STAGES",
    "Pipeline",
    "PipelineParams",
    "PipelineResult",
    "run_pipeline",
    "scale_registration",
]

log = logging.getLogger(__name__)

STAGES = (
    "histograms",
    "response",
    "ratios",
    "registration",
    "response_registered",
    "overlap_histograms",
    "overlap_ratios",
    "merge",
    "preview",
)
ALIGN_CHOICES = ("none", *MODELS, "auto")  # shift, euclidean, similarity, homography
#: Local refinement after the global motion (:mod:`hdrcore.registration.local`): ``"auto"``
#: refines the frames whose pair the independent residual calls misaligned, ``"on"`` every
#: frame; either keeps a field only where it lowers that residual; ``"off"``.
LOCAL_CHOICES = ("auto", "on", "off")
REFINE_CHOICES = ("pixels", "histograms", "none")

ProgressCallback = Callable[[str, float, str], None]

#: The model-error floor of ratios measured through a response recovered from a moved bracket
#: (relative, per stop between the frames). Measured on the seed's hand-held brackets (8 and 12
#: bits, shift <= 20 px, rotation <= 1 deg, 4 scenes x 2 seeds): through the response recovered
#: again after registration, the registered-pixel ratios are off by a median 0.13-0.17 % and up
#: to 2.0-2.4 % (2-stop pairs); the response's shape, not the pixels, carries that error and no
#: jack-knife of one pair sees it (simulated only).
MOVED_RESPONSE_ERROR_PER_STOP = 0.5e-2

#: A not-ok pair whose calibrated 95 % interval holds the EXIF ratio keeps its measured ratio
#: when the interval's relative half-width is at most this; else the merge uses the EXIF ratio.
AGREE_HALF_WIDTH = 0.025

#: Relative disagreement between frames tolerated by the ghost test for non-linear input.
NONLINEAR_MODEL_ERROR = 0.10


class _Unlinked(Exception):  # noqa: N818 - internal signal, never leaves the pipeline
    """Raised by the times stage when a pair has neither a measured ratio nor EXIF times: the
    frames ``keep`` (indices into the bracket run) stay linked, ``drop`` are left out."""

    def __init__(self, keep: tuple[int, ...], drop: tuple[int, ...], why: str) -> None:
        super().__init__(why)
        self.keep, self.drop, self.why = keep, drop, why


def _raise_unlinked(n: int, broken: list[int], why: str) -> None:
    """Pairs ``broken`` (consecutive, ``k``-``k + 1``) have neither a measured ratio nor EXIF
    times: the bracket falls apart into runs of linked frames. The largest run is kept (the
    brighter one on a tie: it holds the mid-tones), the others are left out with a verdict."""
    runs, start = [], 0
    for k in broken:
        runs.append(tuple(range(start, k + 1)))
        start = k + 1
    runs.append(tuple(range(start, n)))
    keep = max(runs, key=lambda run: (len(run), run[-1]))
    if len(keep) < 2:
        raise EstimationError(
            f"the exposure ratio of frames {broken[0]} and {broken[0] + 1} could not be "
            f"measured ({why}) and the frames carry no exposure times to fall back on, so no "
            "two frames are linked; give the times with --times",
        )
    raise _Unlinked(keep, tuple(k for k in range(n) if k not in keep), why)


class Cancelled(Exception):  # noqa: N818 - reads as "raise Cancelled" at the call site
    """Raised by a progress callback to stop a run early (e.g. a newer request superseded it).

    The stages finished before it stay cached; the interrupted stage is not stored.
    """


@dataclass(frozen=True)
class PipelineParams:
    """Parameters of a run. ``None`` means "the default for this bracket".

    saturation, noise_floor : ``Z`` and the noise floor in integer levels (eq. 4 and eq. 6).
    threshold : ``t`` of eq. 7 as a fraction of the saturation level.
    align : ``"none"`` or a motion model of :data:`hdrcore.registration.MODELS`: ``"shift"``,
        ``"euclidean"`` (shift + rotation), ``"similarity"`` (+ scale: a hand-held photographer
        sways and the lens refocuses) or ``"homography"`` (+ perspective); ``"auto"`` (the
        default): similarity, then the homography for each pair whose residual shows
        perspective (or an affine pattern) left, kept when it leaves less (a tripod bracket,
        or a pair the similarity aligns, costs nothing more; with local refinement, 5 of the
        Xperia's 7 pairs and 1 of the Pixel 7's 5 end ok with the similarity, 5 of 7 and 4 of
        5 with auto).
    local : local refinement after the global motion, one of :data:`LOCAL_CHOICES`: a smooth
        displacement field per frame (parallax of near objects, lens), merged through.
    reference : frame the others are warped onto (default: the middle one).
    response : ``"auto"`` (linear for RAW; otherwise the best of the joint recovery, the
        parametric families and sRGB on held-back correspondences, :mod:`hdrcore.response.select`),
        ``"linear"``, ``"srgb"``, a method of :data:`hdrcore.response.RESPONSE_METHODS`, a saved
        curve (``.json`` path) or a :class:`~hdrcore.response.ResponseCurve`.
    times : ``"estimated"`` (the histogram ratios, the paper's method) or ``"exif"``.
    exposure_method, registration_method : names in the stages' registries.
    tonemap, tonemap_exposure : preview operator and exposure in stops; ``"auto"`` (default)
        is the local ``"durand"`` for scenes of more than 8 stops, else ``"reinhard"``
        (:mod:`hdrcore.tonemap`; the preview says which ran and why).
    preview_max_side : longest side of the preview (``None`` = full resolution).
    working_space : colour space of the radiance map (RAW input).
    registration_previews : keep the small before/after overlays of every pair for the
        inspector (the command line switches them off: they cost ~0.3 s a pair at 24 MP).
    registration_max_pixels : frames larger than this register on their green channel binned
        2x2 (or 4x4, ...) until they fit; the motion is scaled back to full resolution
        (``None``, the default: always full resolution, about 0.1 s a pair at 24 MP; binning
        2x2 once took the worst corner error from 0.016 to 0.077 px).
    refine_ratios : after registration, measure the ratios again over each pair's common field
        of view: ``"pixels"`` (default) from the registered pixels themselves
        (:mod:`hdrcore.exposure.registered`), ``"histograms"`` from the histograms of that field
        (:func:`hdrcore.exposure.bracket_exposures_registered`), ``"none"`` keeps the
        whole-frame histogram estimate (the paper's method). Measured on simulated hand-held
        brackets (shift <= 20 px, rotation <= 1 deg): median ratio error 0.003 % (pixels),
        0.06 % (histograms), 2 % (none) at 12 bits.
    exclude_colour : pixels of exactly this colour (levels ``(R, G, B)``) carry no data, e.g.
        the pure blue ``(0, 0, 255)`` border marks of the Debevec-Malik memorial scans: they are
        left out of the histograms and the response wherever any frame has them, and out of the
        merge in the frames that have them.
    ratio_fallback_stops : a pair whose ratio estimate is not ok and differs from the EXIF
        ratio by more than this (stops) uses the EXIF ratio in the merge; the default 0 means
        every not-ok pair with known exposure times uses them (a measurement we do not trust
        is no better than the metadata).
    deghost : fill each region where the frames disagree beyond their noise (the ghost map)
        from one frame, the best exposed there (:mod:`hdrcore.merge.deghost`): a moving object
        comes out whole instead of doubled. Off by default: the weighted average is the
        estimate with the least noise wherever the scene held still.
    colour_anchor : non-linear input (sRGB working space): give each pixel of the merge the
        colour of the frames well exposed there, the one nearest mid-grey first
        (:func:`hdrcore.merge.colour_check.anchor_colour`; the frames decoded with sRGB, as a
        screen shows them, each frame's white balance difference divided out when it was
        corrected), keeping the merge's luminance. The colour is checked before and after
        (``result.colour["check"]``). Not applied to linear-encoded frames (a recovered
        response nearer linear than sRGB, :func:`hdrcore.merge.colour_check.frame_encoding`),
        whose colour the merge already holds.
    white_balance : non-linear input: a frame whose white balance differs from the reference's
        by more than 3 % is divided out of the merge (:mod:`hdrcore.merge.white_balance`; the
        balances are measured and reported either way).
    noise_sigma : the additive noise (levels) the default ratio estimator's noise matching
        assumes (``None``: the noise measured from the frames, ``noise``).
    hold_registration : a previous result's ``registration_inputs`` (its snapped saturation
        level and noise floor, its starting ratios): the registration reads these instead of
        this run's, so it is that result's motion (from the cache) while the merge and
        everything after it use this run's parameters. The inspector's interim picture while a
        slider step registers the frames again (the motion moves by hundredths of a pixel for
        such a step, :meth:`hdrview.session.Session.draft_motion`); ``None`` (the default, and
        what the command line uses): this run's own.
    workers : threads for the compiled kernels, scipy's convention: ``None`` the project's
        default (up to two), ``n`` that many, ``-1`` every core, ``-2`` all but one. No stage
        reads it and no cache key holds it: a kernel's result does not depend on how many
        threads share its rows (tested), so changing it re-runs nothing.
    """

    saturation: float | None = None
    noise_floor: float | None = None
    threshold: float = 0.1
    align: str = "auto"
    local: str = "auto"
    reference: int | None = None
    response: Any = "auto"
    times: str = "estimated"
    exposure_method: str = DEFAULT_EXPOSURE_METHOD
    registration_method: str = "fast"
    tonemap: str = "auto"
    tonemap_exposure: float = 0.0
    preview_max_side: int | None = 2048  # the same as `hdrcore merge --preview-size`
    working_space: str = "sRGB"
    exclude_colour: tuple[int, int, int] | None = None
    ratio_fallback_stops: float = 0.0
    registration_previews: bool = True
    registration_max_pixels: int | None = None
    refine_ratios: str = "pixels"
    deghost: bool = False
    colour_anchor: bool = True
    white_balance: bool = True
    noise_sigma: float | None = None
    hold_registration: tuple[tuple[float, float], tuple[float, ...]] | None = None
    workers: int | None = None

    def replace(self, **changes: Any) -> PipelineParams:
        return replace(self, **changes)

    def to_json(self) -> dict[str, Any]:
        d = asdict(self)
        if isinstance(self.response, ResponseCurve):
            d["response"] = f"<curve: {self.response.method}>"
        return d


@dataclass(frozen=True, eq=False)
class PipelineResult:
    """Everything one run produced; the inspector draws these objects, never recomputes them.

    ``saturation`` / ``noise_floor`` are the values used (levels); ``lut`` the ``(C, L)``
    linearisation (``None`` for RAW: levels are linear); ``exposure_times`` the times the merge
    used (seconds when EXIF anchors them, else relative to the darkest frame) and
    ``times_source`` where they came from; ``radiance`` the merged map in ``working_space``.
    ``stages_run`` lists the stages computed in this run (the others came from the cache).
    ``exposures`` are the ratios the merge used: measured again over each pair's common field
    of view once the registration is known (``overlap_ratios``: from the registered pixels by
    default, see ``PipelineParams.refine_ratios``), else from the whole frames;
    ``exposures_histogram`` always holds the whole-frame estimate (the paper's method, before
    registration). Stages after ``until`` are ``None``.

    ``noise`` is the noise measured from the frames (:mod:`hdrcore.noise`) behind the default
    noise floor and the merge's noise model; ``frame_signals`` says, per frame of the bracket as
    loaded, whether it carries signal (:mod:`hdrcore.signal`). A black or saturated frame is left
    out of every stage: ``bracket`` then holds the frames used (all indices in the stage results
    refer to it), ``full_bracket`` the bracket as loaded and ``unused_frames`` the frames left out
    and why.

    A result is a frozen dataclass, but its arrays are views of the pipeline's cache: the next
    run that hits the cache returns the same arrays, so read them and copy what you change (a
    write into ``radiance`` would change every later cached result); with
    ``Pipeline(reuse_buffers=True)`` or :meth:`Pipeline.release` a later merge overwrites them.
    """

    bracket: Bracket
    params: PipelineParams
    saturation: float
    noise_floor: float
    histograms: BracketHistograms
    response: ResponseCurve | None
    lut: np.ndarray | None
    exposures: BracketExposureResult
    exposures_histogram: BracketExposureResult
    exposure_times: tuple[float, ...]
    times_source: str
    registration: BracketRegistration | None
    merge: MergeResult | None
    radiance: np.ndarray | None = field(repr=False)
    colour: dict[str, Any] = field(default_factory=dict)
    preview: TonemapResult | None = None
    preview_factor: int = 1
    timings: dict[str, float] = field(default_factory=dict)
    stages_run: tuple[str, ...] = ()
    verdicts: tuple[Verdict, ...] = ()
    until: str = "preview"
    noise: BracketNoise | None = None
    frame_signals: tuple[FrameSignal, ...] = ()
    unused_frames: tuple[FrameSignal, ...] = ()
    full_bracket: Bracket | None = None
    #: a pure colour found at the same pixels in every frame (a mask or border marking) and
    #: left out of the estimation as ``exclude_colour`` would (``None``: none found, or the
    #: caller chose ``exclude_colour``)
    marker_colour: tuple[int, int, int] | None = None
    #: per frame, how many pixels have the excluded colour (``None`` without ``exclude_colour``):
    #: a frame where it matches nothing keeps its marks as picture (JPEG cannot hold an exact
    #: colour), which the diagnosis says
    excluded_pixels: tuple[int, ...] | None = None
    #: a run with ``checks="later"``: the call that measures the colour checks (``colour`` has
    #: no ``before`` and ``after`` until :meth:`Pipeline.finish_checks`)
    colour_pending: Callable[[], dict[str, Any]] | None = field(
        default=None, repr=False, compare=False
    )
    #: a non-linear merge's frame measures (white balance, local tone mapping test: what the
    #: colour stage read of the frames alone), for a draft of the same motion and response
    frame_measures: FrameMeasures | None = field(default=None, repr=False, compare=False)
    #: what the registration reads snapped: its saturation level and noise floor, its starting
    #: ratios (:data:`SNAPPED_INPUTS`); another run registers these frames again only when they
    #: differ (or another field it reads does), and ``PipelineParams(hold_registration=...)``
    #: takes them
    registration_inputs: tuple[tuple[float, float], tuple[float, ...]] | None = None

    @property
    def checks_pending(self) -> bool:
        """Measurements that change no pixel were left for later (``Pipeline.run(...,
        checks="later")``): the merge's region ghost test, a non-linear merge's colour checks.
        :meth:`Pipeline.finish_checks` makes them."""
        return self.colour_pending is not None or (
            self.merge is not None and self.merge.ghost_test_pending
        )

    @property
    def ok(self) -> bool:
        return not any(v.severity == "error" for v in self.verdicts)

    @property
    def to_reference(self) -> tuple[np.ndarray, ...]:
        n = len(self.bracket)
        if self.registration is None:
            return tuple(np.eye(2, 3) for _ in range(n))
        if self.registration.to_reference is None:  # homography: 3x3 matrices
            return self.registration.to_reference_homography
        return self.registration.to_reference

    def ratios_json(self) -> dict[str, Any]:
        """The document of ``hdrcore ratios --json``."""
        return ratios_json(self.bracket, self.exposures)

    def registration_json(self) -> dict[str, Any] | None:
        """The document of ``hdrcore align --json`` (``None`` when alignment was off)."""
        if self.registration is None:
            return None
        return registration_json(self.registration, ratios_source=self.times_source)

    @property
    def loaded_bracket(self) -> Bracket:
        """The bracket as loaded (``bracket`` minus nothing), unused frames included."""
        return self.full_bracket if self.full_bracket is not None else self.bracket

    def to_report(self) -> dict[str, Any]:
        """JSON-ready report of the run (no arrays)."""
        b = self.bracket
        return {
            "frames": [
                {
                    **f.meta.to_json(),
                    "index": k,
                    "relative_exposure": self.exposures.relative_exposures[k],
                    "merge_exposure_time": self.exposure_times[k],
                }
                for k, f in enumerate(b.frames)
            ],
            "parameters": {
                **self.params.to_json(),
                "saturation_used": self.saturation,
                "noise_floor_used": self.noise_floor,
            },
            "frames_not_used": [u.to_json() for u in self.unused_frames],
            "frame_signal": [f.to_json() for f in self.frame_signals],
            "noise": None if self.noise is None else self.noise.to_json(),
            "warnings": [w.to_json() for w in self.loaded_bracket.warnings],
            "ratios": self.ratios_json(),
            "ratios_before_registration": ratios_json(self.bracket, self.exposures_histogram),
            "times_source": self.times_source,
            "response": None
            if self.response is None
            else {
                "method": self.response.method,
                "message": getattr(self.response, "message", ""),
                "status": getattr(self.response, "status", "ok"),
                "selection": None
                if getattr(self.response, "selection", None) is None
                else self.response.selection.to_json(),
            },
            "registration": self.registration_json(),
            "merge": None if self.merge is None else self.merge.summary(),
            "colour": self.colour,
            "preview": None
            if self.preview is None
            else {
                **self.preview.to_json(),
                "downsample_factor": self.preview_factor,
            },
            "timings": dict(self.timings),
            "stages_run": list(self.stages_run),
            "verdicts": [v.to_json() for v in self.verdicts],
            "status": "ok" if self.ok else "failed",
        }


def ratios_json(bracket: Bracket, res: BracketExposureResult) -> dict[str, Any]:
    """``{"frames": [...], "pairs": [...]}`` as printed by ``hdrcore ratios --json``."""
    times = bracket.exposure_times
    return {
        "frames": [
            {
                "path": f.meta.path,
                "exif_exposure_time": times[k],
                "relative_exposure": res.relative_exposures[k],
            }
            for k, f in enumerate(bracket.frames)
        ],
        "pairs": [
            {
                "dark": p.dark,
                "bright": p.bright,
                "ratio": p.ratio,
                "initial_ratio": p.initial_ratio,
                "iterations": p.iterations,
                "equations": p.n_equations,
                "inliers": p.n_inliers,
                "exif_ratio": res.exif_ratios[k],
                "mismatch_stops": res.mismatch_stops[k],
                "std_error": p.std_error,
                **{
                    key: value
                    for key, value in p.to_json().items()
                    if key.startswith("ci95") or key == "region_std_error"
                },
                "status": p.status,
                "message": p.message,
            }
            for k, p in enumerate(res.pairs)
        ],
    }


def registration_json(
    reg: BracketRegistration, *, ratios_source: str | None = None
) -> dict[str, Any]:
    """The registration document of ``hdrcore align --json`` and of the merge report (one
    serialiser: :meth:`BracketRegistration.to_json`, each pair's ``to_json``); ``to_reference``
    holds the homographies where the model has no 2x3 form."""
    doc = reg.to_json()
    if doc["to_reference"] is None:
        doc["to_reference"] = doc["to_reference_homography"]
    doc["ratios_source"] = ratios_source
    return doc


class _Context:
    """What every stage may read besides its declared parameters and inputs: the bracket and
    what follows from it alone, fixed for a pipeline's life (its noise, its recorded
    exposures), and the progress report. Never the parameters: those come through the stage's
    declaration."""

    __slots__ = (
        "bracket",
        "no_times",
        "pixel_size",
        "_noise",
        "_report",
        "weight_maps",
        "fixed_registration",
        "fixed_ratios",
        "fixed_frame_measures",
        "colour_report",
        "registration_memo",
    )

    def __init__(
        self,
        bracket: Bracket,
        pixel_size: float,
        noise: Callable[[], BracketNoise],
        report: Callable[[str, float, str], None],
        weight_maps: bool = True,
    ) -> None:
        self.bracket = bracket
        self.weight_maps = weight_maps  # the merge keeps its shares and weight sum
        self.pixel_size = pixel_size
        self._noise = noise
        self._report = report
        self.no_times = not all(e is not None for e in _recorded_exposures(self))
        self.fixed_registration: BracketRegistration | None = None
        self.fixed_ratios: BracketExposureResult | None = None
        self.fixed_frame_measures: FrameMeasures | None = None
        self.colour_report = True  # a non-linear merge's colour measured before and after
        # what a registration of these frames reads again (Pipeline(keep_registration_inputs=))
        self.registration_memo: RunMemo | None = None

    def noise(self) -> BracketNoise:
        return self._noise()

    def report(self, stage: str, fraction: float, message: str) -> None:
        self._report(stage, fraction, message)


class Pipeline:
    """Runs the stages on one bracket, caching each stage by the inputs it depends on.

    Thread-safe: runs are serialised by a lock (the inspector keeps only the latest request).
    ``progress(stage, fraction, message)`` is called as stages start and finish.

    ``reuse_buffers``: a new merge writes into the arrays of the previous one (the cached merge
    when a parameter change makes it stale, or the one :meth:`clear_cache` dropped) instead of
    allocating 28 bytes a pixel afresh, whose first touch costs this VM about 1.7 s of system
    time at 24 MP. Earlier results, their radiance included, are then overwritten by the next
    run and must not be used after it (a command-line run or a viewer that shows only the
    latest result).

    :meth:`release` is the precise form of the same saving, for a caller that keeps showing
    the latest result while the next one is computed: it hands back a result the caller no
    longer uses, and the next merge writes into that one's arrays.

    ``registration``: a motion known already (a draft of a large bracket takes the full
    resolution run's, through :func:`scale_registration`), used by every run that aligns in
    place of the registration stage; it must have a pair per neighbouring frames.

    ``ratios``: the whole-frame exposure ratios known already (a draft that merges with the
    full-resolution run's times takes that run's, which it only reports: 0.3 s of the real
    Xperia bracket's draft), used in place of the ratios stage's fit; it must have a pair per
    neighbouring frames.

    ``frame_measures``: a non-linear bracket's white balance per frame and local tone mapping
    test known already (:func:`~hdrcore.merge.colour_check.measure_frames`; a draft with the
    full-resolution run's motion and response takes that run's, measured on the full frames:
    0.12 s of the 24 MP sRGB bench bracket's draft, 0.27 s of the real Xperia's), used in place
    of measuring them.

    ``colour_report=False`` (a draft: only its picture is shown): a non-linear merge's colour
    is anchored as always but not measured before and after (``result.colour["check"]``'s
    ``before`` and ``after`` are ``None``; 1.1 s of a 2.6 s draft of the real Pixel 7 bracket).
    """

    def __init__(
        self,
        bracket: Bracket,
        params: PipelineParams | None = None,
        *,
        progress: ProgressCallback | None = None,
        reuse_buffers: bool = False,
        pixel_size: float = 1.0,
        weight_maps: bool = True,
        registration: BracketRegistration | None = None,
        colour_report: bool = True,
        ratios: BracketExposureResult | None = None,
        frame_measures: FrameMeasures | None = None,
        keep_registration_inputs: bool = False,
    ) -> None:
        if len(bracket) < 2:
            raise ParameterError("a bracket needs at least two frames", found=str(len(bracket)))
        self.bracket = bracket
        self.params = params or PipelineParams()
        self.progress = progress
        self._pedestal = 0.0
        self._pedestal_key: Any = None
        self._marker_key: tuple[tuple[int, int, int] | None] | None = None
        self._marker_used: tuple[int, int, int] | None = None
        self._lock = threading.Lock()
        self.last_result: PipelineResult | None = None
        self.reuse_buffers = bool(reuse_buffers)
        # Size of the bracket's pixels in the camera's (a binned draft, hdrcore.draft): the
        # local tone operator's scale is in the camera's pixels.
        self.pixel_size = float(pixel_size)
        self._spare: Any = None  # a previous MergeResult whose arrays a new merge may reuse
        self._noise: BracketNoise | None = None
        self._subsets: dict[tuple[int, ...], Pipeline] = {}  # runs without unusable frames
        self._active_subset: Pipeline | None = None
        # Each stage cached by the key its declaration derives (GRAPH, hdrcore.stage_graph).
        # weight_maps=False: the merge of linear input keeps no shares nor weight sum (a caller
        # that reads neither, as ``hdrcore merge``; the report's provenance is counted)
        self.weight_maps = bool(weight_maps)
        self._ctx = _Context(bracket, self.pixel_size, self.noise, self._report, self.weight_maps)
        # registration: a motion known already (a draft's, scaled from the full-resolution run
        # by scale_registration) used in place of the registration stage when a run aligns
        for name, given in (("registration", registration), ("ratios", ratios)):
            if given is not None and len(given.pairs) != len(bracket) - 1:
                raise ParameterError(
                    f"the given {name} must have a pair per neighbouring frames",
                    expected=str(len(bracket) - 1),
                    found=str(len(given.pairs)),
                )
        self._ctx.fixed_registration = registration
        self._ctx.fixed_ratios = ratios
        self._ctx.fixed_frame_measures = (
            None
            if frame_measures is None
            # its own dict for what colour checks measure on these frames (none are shared)
            else FrameMeasures(frame_measures.balance, frame_measures.local_tone_mapping)
        )
        self.colour_report = bool(colour_report)
        self._ctx.colour_report = self.colour_report
        # keep_registration_inputs: a caller that registers these frames again and again (the
        # inspector's threshold, noise floor and saturation sliders) keeps what each pair's
        # search and residual check would make the same (hdrcore.registration._memo): its
        # pyramids, block means and fixed structure images, about 0.15 GB at 24 MP
        self._ctx.registration_memo = RunMemo() if keep_registration_inputs else None
        self._cache = StageCache(
            GRAPH,
            self._ctx,
            on_start=lambda name: self._report(name, 0.0, f"{name}..."),
            on_done=lambda name, dt: self._report(name, 1.0, f"{name} done in {dt:.2f} s"),
        )

    # -- parameter checks ------------------------------------------------------------------

    def _check(self, p: PipelineParams) -> PipelineParams:
        b = self.bracket
        m = b.max_level
        sat = default_saturation(m) if p.saturation is None else float(p.saturation)
        nf = default_noise_floor(m) if p.noise_floor is None else float(p.noise_floor)
        if not (np.isfinite(sat) and 0 < sat <= m):
            raise ParameterError(
                "saturation level out of range", expected=f"0 < Z <= {m}", found=str(p.saturation)
            )
        if not (np.isfinite(nf) and 0 <= nf < sat):
            raise ParameterError(
                "noise floor out of range",
                expected=f"0 <= N < Z = {sat:g}",
                found=f"{nf:.6g}",  # (a default floor of 5.1 levels read 5.1000000000000005)
            )
        if not (np.isfinite(p.threshold) and p.threshold >= 0):
            raise ParameterError("threshold t must be >= 0", found=str(p.threshold))
        align = str(p.align).lower()
        if align not in ALIGN_CHOICES:
            raise ParameterError(
                f"unknown alignment {p.align!r}", expected=f"one of {', '.join(ALIGN_CHOICES)}"
            )
        if str(p.local).lower() not in LOCAL_CHOICES:
            raise ParameterError(
                f"unknown local refinement {p.local!r}",
                expected=f"one of {', '.join(LOCAL_CHOICES)}",
            )
        ref = len(b) // 2 if p.reference is None else int(p.reference)
        if not 0 <= ref < len(b):
            raise ParameterError(
                "reference frame out of range", expected=f"0..{len(b) - 1}", found=str(p.reference)
            )
        if p.refine_ratios not in REFINE_CHOICES:
            raise ParameterError(
                f"unknown ratio refinement {p.refine_ratios!r}",
                expected=f"one of {', '.join(REFINE_CHOICES)}",
            )
        if p.times not in ("estimated", "exif"):
            raise ParameterError(
                f"unknown times source {p.times!r}", expected="'estimated' or 'exif'"
            )
        validate_method(p.exposure_method, EXPOSURE_METHODS, "exposure")
        validate_method(p.registration_method, REGISTRATION_METHODS, "registration")
        validate_method(p.tonemap, TONEMAP_OPERATORS, "tonemap")
        if align not in ("none", "auto"):
            validate_method(align, MODELS, "motion model")
        return replace(
            p,
            saturation=sat,
            noise_floor=nf,
            align=align,
            reference=ref,
            hold_registration=_held_inputs(p.hold_registration, len(b)),
        )

    def stage_seconds(self, stage: str) -> float | None:
        """What computing ``stage``'s current cached value took (seconds, its own time), or
        ``None`` when it holds none: the cost a run that computes it again should expect."""
        with self._lock:
            entry = self._cache.entries.get(stage)
            return None if entry is None else float(entry.seconds)

    def registration_cached(self, params: PipelineParams) -> bool:
        """Whether a run with ``params`` (checked ones: a result's ``params``) finds its
        registration in the cache (``False`` also when it would register a sub-bracket: a
        frame without signal left out). A caller that shows something sooner when the frames
        are to be registered again asks this first (the inspector's interim picture)."""
        with self._lock:
            run = self._cache.run(params)
            if not all(sig.usable for sig in self._signals(params, run)):
                return False
            return self._cache.has("registration", run.key("registration"))

    def noise(self) -> BracketNoise:
        """The noise measured from the frames and the noise floor derived from it
        (:mod:`hdrcore.noise`): the optical-black read noise of RAW files that have masked
        pixels, else a robust estimate from each frame's darkest flat regions (RAW: on the CFA
        mosaic, black level included, so nothing is clipped)."""
        if self._noise is None:
            b = self.bracket
            measured: list[FrameNoise] = []
            for f in b.frames:
                rn = getattr(f.meta, "read_noise", None)
                if rn is not None and math.isfinite(float(rn)) and float(rn) >= 0:
                    # The reader removes the rounding variance; the levels carry it (1/12).
                    measured.append(FrameNoise(math.sqrt(float(rn) ** 2 + 1 / 12), "optical-black"))
                    continue
                cfa = f.cfa
                if f.is_linear and cfa is not None:
                    site = next(
                        (
                            (r, c)
                            for r in range(2)
                            for c in range(2)
                            if cfa.colors[int(cfa.pattern[r, c])] == "G"
                        ),
                        (0, 0),
                    )
                    idx = int(cfa.pattern[site])
                    measured.append(
                        frame_noise(
                            cfa.data[site[0] :: 2, site[1] :: 2],
                            black=float(cfa.black_level[idx]),
                            white=float(cfa.white_level),
                        )
                    )
                else:
                    measured.append(
                        frame_noise(
                            f.levels[..., 1], black=0.0, white=float(f.max_level), clipped_low=0.0
                        )
                    )
            self._noise = bracket_noise(measured, max_level=b.max_level, linear=b.is_linear)
        return self._noise

    def marker_colour(self) -> tuple[int, int, int] | None:
        """A pure colour (each channel 0 or the top level, not grey) at the same pixels in the
        darkest and the brightest frame, on at least 1/10000 of them (of at most 250k pixels on
        a regular lattice, so a 24 MP bracket costs milliseconds): no scene does that across
        an exposure gap, so it is a marking (Debevec's memorial scans paint their border areas
        (0, 0, 255)); ``None`` when there is none or the bracket has one exposure."""
        if self._marker_key is not None:
            return self._marker_key[0]
        b = self.bracket
        found = None
        if len(b) >= 2 and b.frames[0].levels.ndim == 3 and b.frames[0].levels.shape[2] == 3:
            m = b.max_level
            h, w = b.shape
            step = max(1, int(np.sqrt(h * w / 250_000)))  # at most ~250k samples: ms, not s
            lo = b.frames[0].levels[::step, ::step]
            need = max(8, lo.shape[0] * lo.shape[1] // 10000)
            # (channel by channel: numpy's reductions over a last axis of three are slow,
            # 30 ms of every draft of the 24 MP bench bracket)
            lo_c = [lo[..., c] for c in range(3)]
            top = np.maximum(np.maximum(lo_c[0], lo_c[1]), lo_c[2])
            bottom = np.minimum(np.minimum(lo_c[0], lo_c[1]), lo_c[2])
            pure = (top == m) & (bottom == 0)
            if np.count_nonzero(pure) >= need:
                hi = b.frames[-1].levels[::step, ::step]
                best = 0
                for colour in ((m, 0, 0), (0, m, 0), (0, 0, m), (m, m, 0), (m, 0, m), (0, m, m)):
                    same = pure.copy()
                    for c in range(3):
                        same &= (lo_c[c] == colour[c]) & (hi[..., c] == colour[c])
                    n = int(np.count_nonzero(same))
                    if n >= need and n > best:
                        best, found = n, colour
        self._marker_key = (found,)
        return found

    def auto_noise_floor(self, exclude_colour: tuple[int, int, int] | None = None) -> float:
        """Default noise floor: :data:`hdrcore.noise.K_SIGMA` times the noise measured from the
        frames (:meth:`noise`), never below a small minimum, raised above a pedestal.

        A pedestal is a level the darkest frame never goes below (film base and scanner flare,
        a black offset left in a JPEG): levels just above it carry no signal, yet a response
        maps them to non-zero exposure that, divided by the shortest time, swamps the merge.
        It is the highest over the channels of the darkest frame's 0.1th percentile (excluded
        colour left out).
        """
        key = ("pedestal", exclude_colour)
        if self._pedestal_key != key:
            f = self.bracket.frames[0]
            step = max(1, int(np.sqrt(f.levels.shape[0] * f.levels.shape[1] / 1_000_000)))
            lv = f.levels[::step, ::step].reshape(-1, 3)
            if exclude_colour is not None:
                lv = lv[~np.all(lv == np.asarray(exclude_colour), axis=1)]
            # Per channel (film fog and flare differ by colour), the highest one governs.
            self._pedestal = float(np.max(np.percentile(lv, 0.1, axis=0))) if lv.size else 0.0
            self._pedestal_key = key
        base = self.noise().floor
        if self._pedestal > 0.5 * base:
            return float(min(self._pedestal + base, 0.25 * self.bracket.max_level))
        return float(base)

    def frame_signals(
        self,
        p: PipelineParams,
        ran: list[str] | None = None,
        timings: dict[str, float] | None = None,
    ) -> tuple[FrameSignal, ...]:
        """Per frame, whether it carries signal between the noise floor and ``Z`` of ``p``
        (checked parameters), from the cached whole-frame histograms."""
        return self._signals(p, self._cache.run(p, ran, timings))

    def _signals(self, p: PipelineParams, run: Any) -> tuple[FrameSignal, ...]:
        hists = run.get("histograms")
        return tuple(
            frame_signal(
                hists.counts[k],
                noise_floor=_level(p.noise_floor),
                saturation=_level(p.saturation),
                index=k,
                path=f.path,
            )
            for k, f in enumerate(self.bracket.frames)
        )

    # -- cache ------------------------------------------------------------------------------

    def _report(self, stage: str, fraction: float, message: str) -> None:
        if self.progress is not None:
            try:
                self.progress(stage, fraction, message)
            except Cancelled:
                raise
            except Exception:  # a UI callback must never break a run
                log.exception("progress callback failed")

    def _relay_progress(self, stage: str, fraction: float, message: str) -> None:
        if self.progress is not None:
            self.progress(stage, fraction, message)

    def clear_cache(self) -> None:
        with self._lock:
            if self.reuse_buffers and "merge" in self._cache.entries:
                self._spare = self._cache.entries["merge"].value[0]
            self._cache.clear()
            self._subsets.clear()
            self._active_subset = None

    def release(self, result: Any) -> None:
        """The caller no longer uses ``result`` (a :class:`PipelineResult` or its
        :class:`~hdrcore.merge.MergeResult`): the next merge may write into its arrays instead of
        allocating new ones. The merge this pipeline holds in its cache is never taken; an
        earlier released result is simply dropped."""
        merged = getattr(result, "merge", result)
        if merged is None or not hasattr(merged, "radiance"):
            return
        sub = self._active_subset
        if sub is not None and getattr(merged, "n_frames", len(sub.bracket)) == len(sub.bracket):
            sub.release(merged)  # the frames in use are the subset's
            return
        b = self.bracket
        if merged.radiance.shape[:2] != tuple(b.shape) or getattr(
            merged, "n_frames", len(b)
        ) != len(b):
            return  # another bracket's: it does not fit
        with self._lock:
            entry = self._cache.entries.get("merge")
            # (the cached merge, or its completed ghost test: the same arrays)
            if entry is not None and entry.value[0].radiance is merged.radiance:
                return
            self._spare = merged

    def _take_spare(self, merge_key: Any) -> Any:
        """The merge result whose arrays the next merge overwrites: one given to
        :meth:`release`, or with ``reuse_buffers`` the cached one when its key is stale, else one
        kept by :meth:`clear_cache`."""
        if not self.reuse_buffers:
            entry = self._cache.entries.get("merge")
            if entry is not None and entry.key == merge_key:
                return None  # the cached merge serves: keep the released arrays for later
            spare, self._spare = self._spare, None
            return spare
        entry = self._cache.entries.get("merge")
        if entry is not None and entry.key != merge_key:
            self._cache.pop("merge")
            self._cache.pop("preview")
            self._spare = None
            return entry.value[0]
        spare, self._spare = self._spare, None
        return spare

    # -- the run ----------------------------------------------------------------------------

    def run(
        self,
        params: PipelineParams | None = None,
        *,
        until: str = "preview",
        checks: str = "now",
        ghost_test: str | None = None,
    ) -> PipelineResult:
        """Run (or re-use) every stage up to ``until`` and return the result.

        ``until="ratios"`` stops after the whole-frame exposure ratios (a fast re-fit from the
        cached histograms, for sliders); later stages are then ``None`` in the result.

        ``checks="later"``: the merge comes back before the measurements that change no pixel
        (``result.checks_pending``): its region ghost test without deghost
        (``result.merge.ghost_test_pending``, no ghost known yet) and a non-linear merge's
        colour checks before and after the anchoring (``result.colour["check"]`` without
        ``before`` and ``after``; its pixels on the checks' grid kept); :meth:`finish_checks`
        makes them. The inspector shows the picture first, the command writes its EXR while
        they run. ``"now"`` (the default): complete. ``ghost_test``: the former name of
        ``checks``, accepted for one release (``DeprecationWarning``).
        """
        if ghost_test is not None:
            warnings.warn(
                "Pipeline.run(ghost_test=...) is now checks=...",
                DeprecationWarning,
                stacklevel=2,
            )
            checks = ghost_test
        if until not in STAGES:
            raise ParameterError(f"unknown stage {until!r}", expected=", ".join(STAGES))
        if checks not in ("now", "later"):
            raise ParameterError(
                f"unknown checks {checks!r}", expected="now, later", found=str(checks)
            )
        # (the lock is taken before the workers are read: ``with A, B`` enters A first)
        with self._lock, set_workers((params or self.params).workers):
            p_in = params or self.params
            reference = p_in.reference
            marker = None
            if p_in.exclude_colour is None:
                marker = self.marker_colour()
                if marker is not None:
                    p_in = replace(p_in, exclude_colour=marker)
            elif self._marker_key is not None and p_in.exclude_colour == self._marker_key[0]:
                marker = self._marker_key[0]  # a re-run with the parameters of the last one
            self._marker_used = marker
            if p_in.noise_floor is None:
                p_in = replace(p_in, noise_floor=self.auto_noise_floor(p_in.exclude_colour))
            p = self._check(p_in)
            self.params = p
            ran: list[str] = []
            timings: dict[str, float] = {}
            t_start = time.perf_counter()
            run = self._cache.run(p, ran, timings)
            signals = self._signals(p, run)
            if all(sig.usable for sig in signals):
                self._active_subset = None
                try:
                    return self._run(p, STAGES.index(until), signals, run, t_start, checks)
                except _Unlinked as gap:
                    signals = tuple(
                        replace(sig, status="unlinked") if sig.index in gap.drop else sig
                        for sig in signals
                    )
            return self._run_subset(p, reference, signals, until, checks)

    def finish_ghost_test(self, result: PipelineResult) -> PipelineResult:
        """The former name of :meth:`finish_checks`, kept for one release
        (``DeprecationWarning``)."""
        warnings.warn(
            "Pipeline.finish_ghost_test is now finish_checks (it makes the colour checks too)",
            DeprecationWarning,
            stacklevel=2,
        )
        return self.finish_checks(result)

    def finish_checks(self, result: PipelineResult) -> PipelineResult:
        """``result`` (of :meth:`run` with ``checks="later"``) with the measurements it left
        for later made (its merge's region ghost test, its colour checks) and the verdicts
        that read them; ``result`` itself when nothing is pending."""
        if not result.checks_pending:
            return result
        with self._lock:
            res = _checks_done(result)
            if self.last_result is result:
                self.last_result = res
            sub = self._active_subset
            if sub is not None and sub.last_result is not None:
                last = sub.last_result
                if last.merge is result.merge or last.colour_pending is result.colour_pending:
                    sub.last_result = replace(
                        last,
                        merge=res.merge if last.merge is result.merge else last.merge,
                        colour=res.colour,
                        colour_pending=None,
                    )
            return res

    def _run_subset(
        self,
        p: PipelineParams,
        reference: int | None,
        signals: tuple[FrameSignal, ...],
        until: str,
        checks: str = "now",
    ) -> PipelineResult:
        """Run without the frames that carry no signal (black, saturated): they are left out of
        every stage, the rest of the bracket is merged, and the result says which and why."""
        b = self.bracket
        keep = tuple(sig.index for sig in signals if sig.usable)
        unused = tuple(sig for sig in signals if not sig.usable)
        if len(keep) < 2:
            from pathlib import Path

            raise EstimationError(
                "fewer than two frames of the bracket carry signal between the noise floor "
                f"({p.noise_floor:g}) and the saturation level ({p.saturation:g}): "
                + "; ".join(f"{Path(sig.path).name} is {sig.reason}" for sig in unused)
                + ("" if not keep else f"; only {Path(b.frames[keep[0]].path).name} is usable"),
                expected="at least two frames with signal",
                found=f"{len(keep)} usable of {len(b)}",
            )
        sub = self._subsets.get(keep)
        if sub is None:
            sub = Pipeline(
                _sub_bracket(b, keep),
                # this pipeline's callback at each call: a caller sets another one per run
                # (the inspector's checks whether its job is still the latest)
                progress=self._relay_progress,
                reuse_buffers=self.reuse_buffers,
                pixel_size=self.pixel_size,
                weight_maps=self.weight_maps,
                colour_report=self.colour_report,
            )
            sub._noise = self.noise()
            self._subsets[keep] = sub
        self._active_subset = sub
        ref = None
        if reference is not None:
            # The kept frame nearest to the one asked for (the darker one on a tie).
            ref = min(range(len(keep)), key=lambda i: (abs(keep[i] - int(reference)), keep[i]))
        # (a held registration is of the whole bracket's pairs: the subset registers its own)
        res = sub.run(replace(p, reference=ref, hold_registration=None), until=until, checks=checks)
        if res.unused_frames:
            # The subset left more frames out (a ratio gap without EXIF): back to our indices.
            more = {keep[u.index]: replace(u, index=keep[u.index]) for u in res.unused_frames}
            signals = tuple(more.get(sig.index, sig) for sig in signals)
            unused = tuple(sig for sig in signals if not sig.usable)
        res = replace(
            res,
            full_bracket=b,
            unused_frames=unused,
            frame_signals=signals,
            noise=self.noise(),
            marker_colour=self._marker_used,
        )
        res = replace(res, verdicts=tuple(diagnose(res)))
        if until == STAGES[-1] or self.last_result is None:
            self.last_result = res
        return res

    def fields_read(self, stage: str, skip: tuple[str, ...] = ()) -> set[str]:
        """The parameter fields ``stage``'s value depends on for this bracket (not those read
        only through the stages in ``skip``): :meth:`hdrcore.stage_graph.StageGraph.fields_read`."""
        return GRAPH.fields_read(stage, self._ctx, skip)

    def _merge(
        self,
        p: PipelineParams,
        lut: np.ndarray | None,
        times: tuple[float, ...],
        registration: BracketRegistration | None,
        excluded: Any = None,
        reuse: Any = None,
    ) -> tuple:
        """The merge step alone (``bench/bench_merge.py``, ``bench/bench_pipeline.py``)."""
        return _merge_frames(self._ctx, p, lut, times, registration, excluded, reuse=reuse)[:3]

    def _run(
        self,
        p: PipelineParams,
        last: int,
        signals: tuple[FrameSignal, ...],
        run: Any,
        t_start: float,
        checks: str = "now",
    ) -> PipelineResult:
        """The stages up to ``STAGES[last]``: which to ask for, never how they are keyed (each
        stage's key comes from its declaration in :data:`GRAPH`)."""
        b = self.bracket
        upto = STAGES[last]
        ran, timings = run.ran, run.timings

        def want(stage: str) -> bool:
            return STAGES.index(stage) <= last

        hists = run.get("histograms")
        response = run.get("response")
        exposures_hist = run.get("ratios")
        exposures = exposures_hist
        registration = None
        merge_result = None
        radiance = None
        colour_info: dict[str, Any] = {}
        colour_pending: Once[dict[str, Any]] | None = None
        frame_measures: FrameMeasures | None = None
        preview, factor = None, 1
        times, times_source = run.get("times_histogram")
        reg_inputs = (
            tuple(run.get("registration_levels")),
            tuple(run.get("registration_ratios")),
        )
        excluded = run.get("exclusions")
        excluded_pixels = (
            None if excluded is None else tuple(int(np.count_nonzero(m)) for m in excluded[0])
        )
        if want("registration"):
            registration = run.get("registration")
        if want("overlap_ratios"):
            response, _ = run.get("response_used")
            exposures = run.get("exposures")
            times, times_source = run.get("merge_times")
        lut = _lut(self._ctx, response)
        if want("merge"):
            reuse = self._take_spare(run.key("merge"))
            merge_result, radiance, colour_info, colour_pending = run.get("merge", reuse=reuse)
            if lut is not None:
                frame_measures = run.get("frame_measures")
            if want("preview"):
                preview, factor = run.get("preview")
            # the merge stage leaves its region ghost test and colour checks for last (after
            # the preview): made here, once (a cached merge returns the same completed ones)
            if checks == "now" and merge_result.ghost_test_pending:
                t = time.perf_counter()
                merge_result = merge_result.with_ghost_test()
                timings["ghost_test"] = time.perf_counter() - t
            if colour_pending is not None and (checks == "now" or colour_pending.done):
                t = time.perf_counter()
                colour_info = colour_pending()
                timings["colour_checks"] = time.perf_counter() - t
                colour_pending = None
        timings["total"] = time.perf_counter() - t_start
        res = PipelineResult(
            bracket=b,
            params=p,
            saturation=_level(p.saturation),
            noise_floor=_level(p.noise_floor),
            histograms=hists,
            response=response,
            lut=lut,
            exposures=exposures,
            exposures_histogram=exposures_hist,
            exposure_times=times,
            times_source=times_source,
            registration=registration,
            merge=merge_result,
            radiance=radiance,
            colour=colour_info,
            preview=preview,
            preview_factor=factor,
            timings=timings,
            stages_run=tuple(ran),
            until=upto,
            noise=self.noise(),
            frame_signals=signals,
            marker_colour=self._marker_used,
            excluded_pixels=excluded_pixels,
            colour_pending=colour_pending,
            frame_measures=frame_measures,
            registration_inputs=reg_inputs,
        )
        res = replace(res, verdicts=tuple(diagnose(res)))
        if upto == STAGES[-1] or self.last_result is None:
            self.last_result = res
        return res


def _response_registered(
    ctx: _Context,
    p: PipelineParams,
    registration: BracketRegistration,
    hists: BracketHistograms,
    excluded: Any,
) -> ResponseCurve | None:
    """The response recovered again once the motion is known: every frame sampled (nearest
    pixel: levels stay exact) on a grid of the reference frame, over the field of view all
    frames share. The histograms of moved frames see different content at their borders,
    which bends a response recovered before registration: on the seed's 8-bit hand-held
    brackets (<= 20 px, <= 1 deg) the registered ratios through it were up to 5.8 % off."""
    b = ctx.bracket
    h, w = b.shape
    step = max(1, math.ceil(math.sqrt(h * w / 2_000_000)))
    ys, xs = np.mgrid[0:h:step, 0:w:step].astype(np.float64)
    common = np.ones(xs.shape, bool)
    sampled = []
    for k, f in enumerate(b.frames):
        # reference pixel -> frame k pixel (3x3: every model, homographies included)
        xk, yk, inside = nearest_in_frame(registration.to_reference_homography[k], xs, ys, (h, w))
        common &= inside
        sampled.append(np.ascontiguousarray(f.levels[yk, xk]))
        if excluded is not None:
            common &= ~excluded[0][k][yk, xk]
    return _response(ctx, p, hists, excluded, levels=sampled, mask=common)


def _response(
    ctx: _Context,
    p: PipelineParams,
    hists: BracketHistograms,
    excluded: Any,
    levels: list[np.ndarray] | None = None,
    mask: np.ndarray | None = None,
) -> ResponseCurve | None:
    b = ctx.bracket
    spec = p.response
    if isinstance(spec, str) and spec.lower() == "auto" and b.is_linear:
        return None
    if isinstance(spec, str) and spec.lower() == "linear" and b.is_linear:
        return None
    if levels is None:
        levels = [f.levels for f in b.frames]
    exif = _recorded_exposures(ctx)
    known = [float(e) for e in exif if e is not None]
    times: tuple[float, ...] | None = tuple(known) if len(known) == len(exif) else None
    method_names = {k.lower() for k in RESPONSE_METHODS} | {"auto"}
    unused_note = ""
    if isinstance(spec, str) and spec.lower() in method_names and times is None:
        # No exposure times: the ratios measured on sRGB-linearised histograms stand in for
        # them (the response is then fixed up to the usual exponent ambiguity, which the
        # ratios re-measured with the recovered curve absorb).
        rough = bracket_exposures_from_histograms(
            hists,
            method=p.exposure_method,
            lut=srgb_lut(b.max_level),
        )
        rel = np.asarray(rough.relative_exposures, float)
        broken = [
            k for k, pr in enumerate(rough.pairs) if not (np.isfinite(pr.ratio) and pr.ratio > 0)
        ]
        if broken and len(b) > 2:
            _raise_unlinked(len(b), broken, rough.pairs[broken[0]].message)
        if not np.all(np.isfinite(rel) & (rel > 0)):
            raise EstimationError(
                f"response method {spec!r} needs exposure times: the frames carry none "
                "and the histograms could not measure them (" + rough.message + "); give "
                "--times or use --response srgb",
            )
        times = tuple(float(v) for v in rel)
        # Frames too dark for their histograms to be measured (a film scan of 1/1024 s)
        # can come out brighter than their neighbours: the response is fitted on the
        # frames whose rough exposures rise, counted from the brightest down, and says so.
        keep = _rising_from_brightest(rel)
        if len(keep) < len(rel) and len(keep) >= 2:
            left_out = [k for k in range(len(rel)) if k not in keep]
            unused_note = (
                f"fitted without frames {_frame_list(left_out)}: without "
                "exposure times their histograms did not rise with their "
                "brightness (too dark or too flat to measure)"
            )
            levels = [levels[k] for k in keep]
            times = tuple(times[k] for k in keep)
    extra: dict[str, Any] = {}
    if mask is not None and isinstance(spec, str) and spec.lower() in method_names:
        extra["mask"] = mask
    elif excluded is not None and isinstance(spec, str) and spec.lower() in method_names:
        extra["mask"] = ~excluded[1]
    if times is not None and isinstance(spec, str) and spec.lower() in method_names:
        # A doubled shot (two frames of one exposure) adds nothing to the response fit,
        # which needs distinct exposures: one frame of each exposure is used.
        distinct: list[int] = []
        for k, t in enumerate(times):
            if t is None or all(abs(t / times[j] - 1.0) > 1e-3 for j in distinct):
                distinct.append(k)
        if len(distinct) < len(times):
            levels = [levels[k] for k in distinct]
            times = tuple(times[k] for k in distinct)
    curve = resolve_response(spec, levels, times, max_level=b.max_level, n_channels=3, **extra)
    if unused_note and curve is not None:
        curve = replace(curve, message="; ".join(m for m in (curve.message, unused_note) if m))
    return curve


def _exclusions(ctx: _Context, p: PipelineParams):
    """Per-frame masks of pixels of the excluded colour, and their union; or ``None``."""
    if p.exclude_colour is None:
        return None
    colour = np.asarray(p.exclude_colour, dtype=np.int64)
    if colour.shape != (3,) or np.any(colour < 0) or np.any(colour > ctx.bracket.max_level):
        raise ParameterError(
            "exclude_colour must be three levels",
            expected=f"0..{ctx.bracket.max_level}",
            found=str(p.exclude_colour),
        )
    per_frame = colour_masks([f.levels for f in ctx.bracket.frames], colour)
    union = np.logical_or.reduce(per_frame)
    if union.all():
        raise EstimationError(
            f"every pixel has the excluded colour {tuple(int(c) for c in colour)}"
        )
    return tuple(per_frame), union


def _recorded_exposures(ctx: _Context) -> tuple[float | None, ...]:
    """The exposures the metadata records, frame by frame in the bracket's order: time x
    ISO x aperture (phones bracket with ISO), APEX-snapped (:meth:`Bracket.exif_exposures`).

    Times that contradict the frames' brightness order (two lines of a times file swapped,
    see the bracket's ``times-swapped`` warning; the loader orders frames by brightness)
    are taken as the right set of times on the wrong files: sorted, they follow the frames.
    """
    exif = ctx.bracket.exif_exposures()
    known = [e for e in exif if e is not None]
    if len(known) == len(exif) and any(
        t2 < t1 * (1 - 1e-3) for t1, t2 in zip(known, known[1:], strict=False)
    ):
        return tuple(sorted(float(e) for e in known))
    return exif


def _merge_times(
    ctx: _Context, exposures: BracketExposureResult, p: PipelineParams
) -> tuple[tuple[float, ...], str]:
    exif = _recorded_exposures(ctx)
    exif_known = all(e is not None for e in exif)
    if p.times == "exif":
        if not exif_known:
            raise EstimationError(
                "times='exif' needs an exposure time for every frame (EXIF or --times)"
            )
        return tuple(float(e) for e in exif if e is not None), "exif"
    rel = np.asarray(exposures.relative_exposures, float)
    source = "estimated"
    n = len(rel)
    ratios = []
    for k in range(n - 1):
        if np.isfinite(rel[k]) and np.isfinite(rel[k + 1]) and rel[k] > 0:
            ratios.append(float(rel[k + 1] / rel[k]))
        else:  # not connected to frame 0 through measured pairs: the pair's own estimate
            ratios.append(float(exposures.pairs[k].ratio))
    fallback = []
    broken = []
    for k, pair in enumerate(exposures.pairs):
        r = ratios[k]
        e0, e1 = exif[k], exif[k + 1]
        exif_r = None if e0 is None or e1 is None else e1 / e0
        good = math.isfinite(r) and r > 0
        lo, hi = pair.interval
        # Within a tight enough interval (half-width <= 2.5 %), a measured ratio that holds
        # the EXIF ratio is the better of the two; a wider one says little either way.
        agrees = (
            exif_r is not None
            and good
            and lo <= exif_r <= hi
            and hi / lo <= (1 + AGREE_HALF_WIDTH) / (1 - AGREE_HALF_WIDTH)
        )
        if exif_r is not None and (
            not good
            or (not pair.ok and not agrees and abs(math.log2(r / exif_r)) >= p.ratio_fallback_stops)
        ):
            # An unreliable estimate far from the metadata: trust the metadata here. (An
            # estimate whose 95 % interval holds the APEX-snapped EXIF ratio agrees with it
            # and is kept: it measures what the shutter really did.)
            ratios[k] = float(exif_r)
            fallback.append(k)
        elif not good:
            broken.append(k)
    if broken:
        _raise_unlinked(n, broken, exposures.pairs[broken[0]].message)
    rel = np.concatenate([[1.0], np.cumprod(ratios)])
    if fallback:
        source = "estimated; EXIF for pairs " + ", ".join(f"{k}-{k + 1}" for k in fallback)
    known = [(k, float(e)) for k, e in enumerate(exif) if e is not None]
    if known:
        # Anchor the relative exposures to seconds with the geometric mean of the metadata.
        scale = math.exp(float(np.mean([math.log(e / rel[k]) for k, e in known])))
    else:
        scale = 1.0
    return tuple(float(v * scale) for v in rel), source


def _pixel_ratios(
    ctx: _Context,
    p: PipelineParams,
    lut: np.ndarray | None,
    registration: BracketRegistration,
    fallback: BracketExposureResult,
    excluded: Any,
) -> BracketExposureResult:
    b = ctx.bracket
    masks = None if excluded is None else [~mask for mask in excluded[0]]
    # The registered-pixel estimator samples each pair through its matrix: affine, or
    # the homography of a pair registered with perspective.
    common: dict[str, Any] = dict(
        registered=[q.usable for q in registration.pairs],
        fallback=fallback,
        exposure_times=b.exif_exposures(),
        saturation=p.saturation,
        noise_floor=p.noise_floor,
    )
    # Each pair compared where the merge takes its pixels: in place when the merge reads both
    # frames in place (motion below what the registration resolves, _reading_chain), so a
    # tripod bracket registered again (a threshold step) measures the same ratios and keeps
    # its merge; through the pair's motion otherwise.
    reading = _reading_chain(registration, b.shape[:2])
    matrices = [
        np.eye(3) if reading[q.dark] is None and reading[q.bright] is None else _pair_motion(q)
        for q in registration.pairs
    ]
    cfas = [f.cfa for f in b.frames if f.cfa is not None]
    cfa_ok = (
        masks is None
        and lut is None
        and len(cfas) == len(b.frames)
        and all(
            c.data.shape == f.levels.shape[:2] and (f.meta.orientation in (None, 1))
            for c, f in zip(cfas, b.frames, strict=True)
        )
    )
    if cfa_ok:
        # RAW: compare the sensor's own CFA sites, not demosaiced values (demosaicing is
        # not linear in the exposure; see hdrcore.exposure.registered.cfa_planes).
        planes = [cfa_planes(c.data, c.pattern, c.colors, c.black_level, b.max_level) for c in cfas]
        return bracket_exposures_from_pixels(
            [pl[0] for pl in planes],
            b.max_level,
            matrices,
            geometry=planes[0][1],
            channel_groups=planes[0][2],
            **common,
        )
    return bracket_exposures_from_pixels(
        [f.levels for f in b.frames], b.max_level, matrices, masks=masks, lut=lut, **common
    )


def _pair_motion(q: PairRegistration) -> np.ndarray:
    """The pair's 2x3 matrix (affine models), else its 3x3 homography (it has one or the
    other: ``PairRegistration`` refuses neither)."""
    motion = q.matrix if q.matrix is not None else q.homography
    if motion is None:
        raise ValueError(f"pair {q.dark}-{q.bright} has no motion")
    return motion


def _level(value: float | None) -> float:
    """A level of checked parameters (``Pipeline._check`` replaced each ``None`` by its value:
    the saturation level and the noise floor)."""
    if value is None:
        raise TypeError("the parameters were not checked: a level is still None")
    return float(value)


def _linear_level(
    ctx: _Context, lut: np.ndarray | None, level: float | None, channel: int = 1
) -> float:
    m = ctx.bracket.max_level
    if lut is None:
        return _level(level) / m
    return float(np.interp(_level(level), np.arange(m + 1), lut[channel]))


def scale_registration(
    reg: BracketRegistration, factor: float, shape: tuple[int, int], note: str = ""
) -> BracketRegistration:
    """``reg`` expressed on frames resampled by ``factor`` (2: twice the size; 1/4: binned 4x4)
    of size ``shape``: each pair's motion conjugated by the change of pixel grid
    (:func:`hdrcore.geometry.scale_matrix`), the per-frame chain to the reference rebuilt,
    ``note`` appended to each pair's message. Residual measurements are kept as they were
    (in the frames they were measured on)."""
    h, w = shape
    pairs = []
    for q in reg.pairs:
        # the motion on the new grid: the 2x3 matrix of an affine model (the homography
        # follows from it), else the homography (a perspective pair has no 2x3 form)
        affine = q.matrix is not None
        mat = (
            scale_matrix(_pair_motion(q), float(factor))
            if q.usable
            else np.eye(2, 3)
            if affine
            else np.eye(3)
        )
        dx, dy, angle = rigid_parameters(mat, (h, w))
        preview = q.preview
        if preview is not None:
            preview = replace(preview, scale=preview.scale / factor)
        pairs.append(
            replace(
                q,
                matrix=mat if affine else None,
                homography=None if affine else mat,
                dx=dx,
                dy=dy,
                angle_deg=angle,
                shape=(h, w),
                initial_shift=(q.initial_shift[0] * factor, q.initial_shift[1] * factor),
                preview=preview,
                message=q.message + note,
            )
        )
    matrices = [q.matrix for q in pairs]
    if all(m is not None for m in matrices):
        chain = to_reference([m for m in matrices if m is not None], reg.reference)
        return replace(reg, pairs=tuple(pairs), to_reference=chain)
    chain = to_reference([_pair_motion(q) for q in pairs], reg.reference)
    return replace(reg, pairs=tuple(pairs), to_reference=None, to_reference_homography=chain)


def _register(
    ctx: _Context, p: PipelineParams, lut: np.ndarray | None, ratios: tuple[float, ...]
) -> BracketRegistration | None:
    if p.align == "none":
        return None
    b = ctx.bracket
    h, w = b.shape
    factor = 1
    limit = p.registration_max_pixels
    while limit is not None and (h // factor) * (w // factor) > limit:
        factor *= 2
    extra: dict[str, Any] = {}
    if factor == 1:
        # The green levels read in place through a table: no float copy of the frames.
        images = [f.levels[..., 1] for f in b.frames]
        m = b.max_level
        extra["lut"] = (
            np.arange(m + 1, dtype=np.float32) * np.float32(1.0 / m)
            if lut is None
            else lut[1].astype(np.float32)
        )
    else:
        # Large frames register on their green channel binned factor x factor: a quarter
        # of the memory traffic per halving, and the pyramid's finest level still resolves
        # hundredths of a (binned) pixel; the motion is scaled back to full resolution.
        images = []
        for f in b.frames:
            binned = bin_channel(f.levels, 1, factor)
            if lut is None:
                binned *= np.float32(1.0 / f.max_level)
            else:
                binned = np.interp(binned, np.arange(lut.shape[1]), lut[1]).astype(np.float32)
            images.append(binned)

    def progress(done: int, total: int) -> None:
        ctx.report("registration", done / total, f"registered pair {done} of {total}")

    search = dict(
        method=p.registration_method,
        saturation=_linear_level(ctx, lut, p.saturation),
        noise_floor=_linear_level(ctx, lut, p.noise_floor),
        threshold=p.threshold,
        previews=p.registration_previews,
        **extra,
    )
    memo = ctx.registration_memo if factor == 1 else None
    if memo is not None:
        search["memo"] = memo
        memo.new_run()
    if factor == 1:
        # each pair checked independently as it is registered, and searched again without a
        # nearer object the check finds (register_pair's check_residual; _with_residuals
        # then keeps these measurements)
        search["check_residual"] = True
    then: Callable[[PairRegistration], PairRegistration] | None = None
    if factor == 1:
        # each pair measured (and, with "auto", tried with the homography) on its worker as
        # soon as it is registered: no pair waits for the others' first pass
        measure = _residual_measure(ctx, p, lut)
        then = measure
        if p.align == "auto":
            then = partial(_upgraded_pair, measure, images, ratios, search)
    reg = register_bracket(
        images,
        ratios,
        reference=p.reference,
        model="similarity" if p.align == "auto" else p.align,
        progress=progress,
        then=then,
        **search,
    )
    if memo is not None:
        memo.end_run()
    if factor == 1:
        if p.align == "auto" and any(q.model != reg.model for q in reg.pairs):
            reg = replace(reg, model="auto")  # pairs of both models, chained as 3x3 matrices
        if p.local != "off":
            reg = _refine_locally(ctx, reg, images, p, lut, extra["lut"])
        return reg
    full = scale_registration(
        reg,
        float(factor),
        (h, w),
        note=f" (registered on the green channel binned {factor}x{factor})",
    )
    return _with_residuals(ctx, full, p, lut)


def _refine_locally(
    ctx: _Context,
    reg: BracketRegistration,
    images: list,
    p: PipelineParams,
    lut: np.ndarray | None,
    table: np.ndarray,
) -> BracketRegistration:
    """Local refinement (:func:`hdrcore.registration.local.refine_bracket`) on the green
    levels: with ``local="auto"`` only the frames whose pair the independent residual calls
    misaligned are refined (a tripod bracket costs nothing); a field is kept where it lowers
    that residual. A weak pair whose residual the field brings under the threshold becomes
    ``ok``, and says so."""
    from .registration.local import refine_bracket

    pairs = reg.pairs
    if not pairs or not all(q.usable for q in pairs):
        return reg
    refine = [
        p.local == "on" or (q.residual is not None and q.residual.status == "misaligned")
        for q in pairs
    ]
    if not any(refine):
        return reg
    exposures = [float(e) for e in np.cumprod([1.0] + [float(q.ratio) for q in pairs])]

    def progress(done: int, total: int) -> None:
        ctx.report("registration", 1.0, f"local refinement: frame {done} of {total}")

    local = refine_bracket(
        images,
        exposures,
        reg.to_reference_homography,
        reg.reference,
        saturation=_linear_level(ctx, lut, p.saturation),
        noise_floor=_linear_level(ctx, lut, p.noise_floor),
        lut=table,
        threshold=p.threshold,
        refine=refine,
        progress=progress,
    )
    out = list(pairs)
    for fr in local.frames:
        i = min(fr.frame, fr.against)
        q = out[i]
        if not fr.kept:
            continue
        if q.status == "weak" and fr.after_status == "aligned":
            out[i] = replace(
                q,
                status="ok",
                message=(
                    f"aligned after local refinement ({fr.before:.2f} -> {fr.after:.2f} px "
                    f"median); the global model alone: {q.message}"
                ),
            )
        else:
            out[i] = replace(
                q,
                message=q.message
                + (f"; local refinement: {fr.before:.2f} -> {fr.after:.2f} px median"),
            )
    return replace(reg, pairs=tuple(out), local=local)


def _upgraded_pair(
    measure: Callable[[PairRegistration], PairRegistration],
    images: list,
    ratios: tuple,
    search: dict,
    q: PairRegistration,
) -> PairRegistration:
    """``--align auto``: the pair measured (``measure``: :func:`_residual_measure`'s); a pair
    the residual check calls misaligned after the similarity is
    registered again with the homography model, which is kept when its own residual is
    smaller (median over the tiles, or aligned where the similarity was not). The
    simplest model that explains the motion stays. Every misaligned pair is tried, not
    only those whose residual shows a perspective pattern: on the Xperia bracket the pair
    whose residual read as "local" (0.87 px median) was left at the similarity while the
    homography leaves 0.33 px."""
    q = measure(q)
    res = q.residual
    if not (q.status == "weak" and res is not None and res.status == "misaligned"):
        return q
    i = q.dark
    h = register_pair(
        images[i],
        images[i + 1],
        ratios[i],
        model="homography",
        dark_index=i,
        bright_index=i + 1,
        **search,
    )
    if not h.usable:
        return q
    h = measure(h)
    if h.residual is None:
        return q
    hr = h.residual
    better = (hr.aligned and not res.aligned) or (
        math.isfinite(hr.median) and hr.median < 0.8 * res.median
    )
    # a global pattern left by the similarity (a perspective tilt at the corners) that
    # the homography removes, the tiles no worse: the Pixel 7's darkest pair leaves a 4.0
    # px tilt, 0.45 / 1.82 px median / 90th percentile, which the homography takes to
    # 0.38 / 1.18 px with no pattern left
    left, after = _pattern_px(res), _pattern_px(hr)
    removes = (
        res.kind in PATTERN_COMPONENTS
        and math.isfinite(left)
        and math.isfinite(after)
        and after <= 0.5 * left
        and hr.median <= res.median
        and hr.p90 <= res.p90
    )
    if not (better or removes):
        return q
    said = (
        f"{res.median:.2f} px median"
        if better
        else f"{res.median:.2f} px median and a {res.kind} pattern of {left:.1f} px"
    )
    return replace(
        h,
        message=h.message + f" (auto: the similarity left "
        f"{said}, the homography {hr.median:.2f} px"
        f"{'' if better else f' and {after:.1f} px'})",
    )


def _pattern_px(res) -> float:
    """The largest global pattern component a residual measurement found, px at the corners
    (NaN without a pattern)."""
    if res is None or res.pattern is None:
        return float("nan")
    return float(max(res.pattern.component_px().values()))


def _with_residuals(
    ctx: _Context, reg: BracketRegistration, p: PipelineParams, lut: np.ndarray | None
) -> BracketRegistration:
    """Each registered pair checked by :func:`_residual_measure`'s measurement."""
    measure = _residual_measure(ctx, p, lut)
    return replace(reg, pairs=tuple(measure(q) for q in reg.pairs))


def _residual_measure(
    ctx: _Context, p: PipelineParams, lut: np.ndarray | None
) -> Callable[[PairRegistration], PairRegistration]:
    """A registered pair checked by a measurement that shares nothing with the search
    (:func:`hdrcore.registration.residual.residual_motion`: phase correlation of tiles of
    the aligned frames' structure): a pair is ``ok`` only when what is left is small and
    unstructured; otherwise ``weak`` (its motion is still used) with a message saying what
    is left and where (:func:`hdrcore.registration._problem.judge_residual`, the words
    register_pair's own check uses). A failed pair, or one register_pair measured, is kept."""
    from .registration._problem import judge_residual
    from .registration.residual import residual_motion

    b = ctx.bracket
    m = b.max_level
    table = (
        np.arange(m + 1, dtype=np.float32) * np.float32(1.0 / m)
        if lut is None
        else lut[1].astype(np.float32)
    )
    sat = _linear_level(ctx, lut, p.saturation)
    floor = _linear_level(ctx, lut, p.noise_floor)

    def measure(q: PairRegistration) -> PairRegistration:
        if not q.ok or q.residual is not None:  # failed, or measured by register_pair
            return q
        try:
            res = residual_motion(
                b.frames[q.dark].levels[..., 1],
                b.frames[q.bright].levels[..., 1],
                float(q.ratio),
                np.asarray(q.homography),
                saturation=sat,
                noise_floor=floor,
                lut=table,
            )
        except (ValueError, ParameterError) as exc:  # too small a frame to tile
            log.debug("residual of pair %d-%d not measured: %s", q.dark, q.bright, exc)
            return q
        status, message = judge_residual(res, np.asarray(q.homography), q.model, q.message, q.shape)
        return replace(q, status=status, message=message, residual=res)

    return measure


#: A frame whose motion moves no corner of it by this many pixels is merged where it lies
#: (read in place, not resampled): below what the registration resolves where nothing moved
#: (the real tripod frobisher bracket: 0.05-0.08 px found at the corners; simulated tripod
#: brackets 0.001-0.02 px). Measured: frobisher's merge the same to 0.02 % (median) but at its
#: borders, which the resampled frames' 4x4 supports left to one frame (a dark column at the
#: left edge, up to 118 of 255 levels in the preview); simulated tripod brackets (6 MP, linear
#: 16-bit and sRGB 8-bit) 4.5e-4 -> 3.9e-4 and 0.0085 -> 0.0084 median relative error against
#: the truth; the 24 MP bench bracket's merge kernel 1.5 -> 0.9 s.
MIN_APPLIED_MOTION_PX = 0.1


def _negligible_motion(to_ref: np.ndarray, shape: tuple[int, int]) -> bool:
    """Whether ``to_ref`` moves no corner of a frame of ``shape`` by
    :data:`MIN_APPLIED_MOTION_PX` or more (the identity to rounding when it is 0)."""
    if np.allclose(to_ref, np.eye(3), atol=1e-9):
        return True
    return bool(
        np.max(corner_error(np.asarray(to_ref, np.float64), np.eye(3), shape))
        < MIN_APPLIED_MOTION_PX
    )


def _reading_chain(
    registration: BracketRegistration | _Reading, shape: tuple[int, ...]
) -> list[np.ndarray | None]:
    """Per frame the 3x3 matrix (frame -> reference) through which the merge reads it, or
    None where it reads the frame in place: the reference, and a frame whose motion is
    negligible (:data:`MIN_APPLIED_MOTION_PX`; unless a local field moves it)."""
    chain = registration.to_reference_homography
    hw = (int(shape[0]), int(shape[1]))
    return [
        None
        if k == registration.reference
        or (registration.local is None and _negligible_motion(chain[k], hw))
        else chain[k]
        for k in range(len(chain))
    ]


@dataclass(frozen=True)
class _Reading:
    """What the merge and the frame measures read of a registration: per frame the 3x3 matrix
    (frame -> reference) through which the merge reads it, the identity where it reads the frame
    in place (:func:`_reading_chain`), the reference and the local fields. A value stage: a
    re-registration that leaves every frame where the merge reads it (a tripod bracket, whose
    frames moved by less than :data:`MIN_APPLIED_MOTION_PX`, after a step of the threshold t)
    keeps their cached results, which would come out the same to the bit."""

    reference: int
    to_reference_homography: tuple[np.ndarray, ...]
    local: Any = None


def _read_in_place(
    registration: BracketRegistration | _Reading, shape: tuple[int, ...]
) -> list[np.ndarray]:
    """The chain to the reference with the identity for the frames the merge reads in place
    (:func:`_reading_chain`): the colour checks and the anchoring read each frame's pixels where
    the merge took them (and skip a per-pixel mapping of those frames)."""
    return [np.eye(3) if m is None else m for m in _reading_chain(registration, shape)]


def _merge_frames(
    ctx: _Context,
    p: PipelineParams,
    lut: np.ndarray | None,
    times: tuple[float, ...],
    registration: BracketRegistration | _Reading | None,
    excluded: Any = None,
    reuse: Any = None,
    defer_ghost_test: bool = False,
    frame_measures: FrameMeasures | None = None,
    colour_later: bool = False,
) -> tuple[MergeResult, np.ndarray, dict[str, Any], Once[dict[str, Any]] | None]:
    """The merge, its radiance, its colour (``result.colour``) and, with ``colour_later`` (and
    a non-linear bracket whose colour is reported: ``ctx.colour_report``), the call that
    measures the colour checks (:func:`check_colour`'s ``report="later"``) and returns the
    colour with them; else ``None`` (measured already, or never)."""
    b = ctx.bracket
    n = len(b)
    levels = [f.levels for f in b.frames]  # the bracket's own arrays: no copies
    transforms: list[np.ndarray | None] | None = None
    if registration is not None:
        # The merge samples each frame at the reference pixel mapped into it (Keys cubic on
        # the integer levels; a frame whose 4x4 support touches a clipped sample counts as
        # clipped there): no warped copies of the frames. 3x3: homographies too.
        reading = _reading_chain(registration, b.shape[:2])
        transforms = [None if r is None else invert(r) for r in reading]
    masks: list[np.ndarray | None] | None = None
    if excluded is not None:
        masks = []
        for k in range(n):
            gone = excluded[0][k]
            if registration is not None and transforms is not None and transforms[k] is not None:
                moved = warp_to_reference(
                    gone.astype(np.float32), registration.to_reference_homography[k], fill=0.0
                ).image
                masks.append(~(moved > 0.01))
            else:
                masks.append(~gone)
    noise = _noise_model(b, ctx.noise())
    colour, colour_info = _colour(ctx, p)
    result = merge(
        levels,
        times,
        response=lut,
        max_level=b.max_level,
        masks=masks,
        saturation_level=_level(p.saturation),
        noise_floor=_level(p.noise_floor),
        weighting="noise-aware" if lut is None else "hat-noise-aware",
        noise=noise,
        transforms=transforms,
        fields=None
        if registration is None or registration.local is None
        else list(registration.local.fields),
        # A recovered response and 8-bit (often JPEG or scanned) data agree between frames
        # only to a few per cent; RAW data to the noise.
        model_error=DEFAULT_MODEL_ERROR if lut is None else NONLINEAR_MODEL_ERROR,
        reuse=reuse,
        colour=colour,  # converted inside the merge's finishing pass
        deghost=bool(p.deghost),
        defer_ghost_test=defer_ghost_test,
        weight_maps=ctx.weight_maps or lut is not None,  # the colour check reads the shares
        progress=lambda fraction, message: ctx.report("merge", fraction, message),
    )
    if lut is not None:
        # Non-linear input: the merge's colour checked against the frames and (sRGB
        # working space) anchored to them; local tone mapping tested (issue 15).
        checked = check_colour(
            levels,
            result.radiance,
            lut,
            max_level=b.max_level,
            reference=0 if registration is None else registration.reference,
            saturation=_level(p.saturation),
            noise_floor=_level(p.noise_floor),
            to_reference=None if registration is None else _read_in_place(registration, b.shape),
            masks=None if excluded is None else [~e for e in excluded[0]],
            anchor=bool(p.colour_anchor) and colour is None,
            white_balance=bool(p.white_balance),
            exposure_times=times,
            shares=result.shares,
            frame_measures=frame_measures,
            report=("later" if colour_later else True) if ctx.colour_report else False,
        )
        colour_info["check"] = checked.to_json()
        source = colour_info.get("source_space", "sRGB")
        if colour is None and source != "sRGB":
            # frames in Display P3 or Adobe RGB: checked and anchored in their own primaries,
            # then taken to the working space
            convert_space_in_place(result.radiance, space_to_space_matrix(source, p.working_space))
            colour_info["conversion"] += f", converted to {p.working_space} after the colour check"
        if checked.pending is not None:
            return result, result.radiance, colour_info, _colour_measured(checked, colour_info)
    return result, result.radiance, colour_info, None


def _colour_measured(checked: ColourResult, colour_info: dict[str, Any]) -> Once[dict[str, Any]]:
    """The call that completes a merge's ``colour_info`` with its colour checks (measured
    once, whoever asks first; every call returns the same dict)."""
    return Once(lambda: {**colour_info, "check": checked.measured().to_json()})


def _checks_done(result: PipelineResult) -> PipelineResult:
    """``result`` with its pending region ghost test and colour checks made (timed) and its
    verdicts drawn again."""
    timings = dict(result.timings)
    merged = result.merge
    colour = result.colour_pending

    def timed(name: str, fn: Callable[[], Any]) -> Any:
        t = time.perf_counter()
        out = fn()
        timings[name] = time.perf_counter() - t
        return out

    jobs: list[tuple[str, Callable[[], Any]]] = []
    if merged is not None and merged.ghost_test_pending:
        jobs.append(("ghost_test", merged.with_ghost_test))
    if colour is not None:
        jobs.append(("colour_checks", colour))
    # side by side: the ghost test's compiled chains and the checks' mostly single-threaded
    # numpy (real Xperia bracket: 1.8 s and 0.9 s in a row)
    done = dict(zip((n for n, _ in jobs), thread_map(lambda job: timed(*job), jobs), strict=True))
    res = replace(
        result,
        merge=done.get("ghost_test", merged),
        colour=done.get("colour_checks", result.colour),
        colour_pending=None,
        timings=timings,
    )
    return replace(res, verdicts=tuple(diagnose(res)))


def _colour(ctx: _Context, p: PipelineParams) -> tuple[ColourConversion | None, dict[str, Any]]:
    """The camera RGB -> working space conversion the merge applies, and its description.
    Pixels clipped in every frame come out neutral (no magenta highlights)."""
    b = ctx.bracket
    info: dict[str, Any] = {"working_space": p.working_space}
    f0 = b.frames[0].meta
    if b.is_linear and f0.rgb_xyz_matrix is not None and np.any(np.asarray(f0.rgb_xyz_matrix) != 0):
        info["conversion"] = "camera matrix (rawpy rgb_xyz_matrix) and as-shot WB"
        return colour_conversion(
            np.asarray(f0.rgb_xyz_matrix), f0.camera_whitebalance, p.working_space
        ), info
    if b.is_linear:
        info["conversion"] = (
            "no camera matrix in the file: camera RGB taken as linear sRGB primaries, "
            "as-shot white balance applied"
        )
        return colour_conversion(None, f0.camera_whitebalance, p.working_space), info
    source, where = _frames_space(b)
    info["conversion"] = f"linearised {source}-primaries data" + (f" ({where})" if where else "")
    info["source_space"] = source
    if p.working_space.lower() != "srgb":
        return colour_conversion(None, None, p.working_space, source_space=source), info
    # the sRGB working space: the merge stays in the frames' primaries for the colour check and
    # anchoring (they compare it with the frames) and is converted after them (_merge_frames)
    return None, info


def _frames_space(b: Bracket) -> tuple[str, str]:
    """The RGB space a non-linear bracket's levels are encoded in (the one most of its frames
    name; sRGB when none does) and where it was read."""
    named = [f.meta.colour_space for f in b.frames if f.meta.colour_space is not None]
    if not named:
        return "sRGB", ""
    source = max(set(named), key=named.count)
    where = next(
        f.meta.colour_space_source or "" for f in b.frames if f.meta.colour_space == source
    )
    return source, where


def _preview(ctx: _Context, p: PipelineParams, radiance: np.ndarray) -> tuple[TonemapResult, int]:
    """The preview of ``radiance`` tone mapped, and its downsampling factor."""
    factor = downsample_factor(radiance.shape[:2], p.preview_max_side)
    small = downsample_area(radiance, factor) if factor > 1 else radiance
    return tonemap(
        small, p.tonemap, exposure=p.tonemap_exposure, pixel_size=factor * ctx.pixel_size
    ), factor


def _fusion_preview(
    ctx: _Context, p: PipelineParams, registration: BracketRegistration | None
) -> tuple[TonemapResult, int]:
    """Locally tone-mapped frames: no radiance map is right, so the preview is their exposure
    fusion (Mertens et al. 2007), the frames' own colours and contrast; and its factor."""
    factor = downsample_factor(ctx.bracket.shape, p.preview_max_side)
    t0 = time.perf_counter()
    image = exposure_fusion(
        [f.levels for f in ctx.bracket.frames],
        max_level=ctx.bracket.max_level,
        to_reference=None if registration is None else registration.to_reference_homography,
        factor=factor,
    )
    return TonemapResult(
        image=image,
        method=FUSION_METHOD,
        exposure=0.0,
        key=0.0,
        auto_exposure=False,
        log_average=float("nan"),
        scale=1.0,
        white=None,
        timings={"total": time.perf_counter() - t0},
    ), factor


def _sub_bracket(b: Bracket, keep: tuple[int, ...]) -> Bracket:
    """The bracket of frames ``keep`` (indices into ``b``), its warnings re-indexed."""
    new_index = {k: i for i, k in enumerate(keep)}
    # What a left-out frame's own warnings said (black, saturated, darker than a shorter
    # exposure) is said again, better, by the verdict on the frames not used.
    about_frame = {"frame-black", "frame-saturated", "out-of-order", "times-swapped"}
    warnings = tuple(
        replace(w, frames=tuple(new_index[k] for k in w.frames if k in new_index))
        for w in b.warnings
        if not (w.code in about_frame and any(k not in new_index for k in w.frames))
    )
    return Bracket(
        frames=tuple(b.frames[k] for k in keep),
        warnings=warnings,
        order_source=b.order_source,
        input_order=tuple(b.input_order[k] for k in keep),
    )


def colour_masks(levels: list[np.ndarray], colour) -> list[np.ndarray]:
    """Per frame, True where a pixel of ``(H, W, 3)`` levels is exactly ``colour``."""
    c = np.asarray(colour, dtype=np.int64)
    return [(lv[..., 0] == c[0]) & (lv[..., 1] == c[1]) & (lv[..., 2] == c[2]) for lv in levels]


def _noise_model(bracket: Bracket, noise: BracketNoise) -> NoiseModel:
    """The merge's noise model (weights and ghost test) from the noise measured on the frames:
    RAW, read noise ``sigma / max_level`` (at least one level: demosaicing and black-level
    drift add to the measured sigma); non-linear frames, noise in output levels (at least one
    level, JPEG compression)."""
    m = bracket.max_level
    sigma = noise.sigma if math.isfinite(noise.sigma) else 0.0
    if bracket.is_linear:
        return NoiseModel(read_noise=max(sigma, 1.0) / m, full_well=None, level_noise=0.0)
    return NoiseModel(read_noise=0.0, full_well=None, level_noise=max(sigma, 1.0))


def _with_response_error(res: BracketExposureResult, per_stop: float) -> BracketExposureResult:
    """``res`` with every pair's model-error floor raised to ``per_stop`` per stop (the
    response was recovered from a moved bracket), the pairs judged again and the chain solved
    again with their new weights."""

    def one(q: ExposureRatioResult) -> ExposureRatioResult:
        return judge(replace(q, response_error_per_stop=per_stop))

    tail = "; ratios from the registered pixels of each pair"
    return assemble_bracket(
        len(res.relative_exposures),
        [one(q) for q in res.pairs],
        [one(q) for q in res.extra_pairs],
        method=res.method,
        max_level=res.max_level,
        exposure_times=res.exif_times,
        message_suffix=tail if res.message.endswith(tail) else "",
    )


def _recovered(spec: Any) -> bool:
    """Whether ``--response`` asks for a curve recovered from the bracket itself."""
    if not isinstance(spec, str):
        return False
    name = spec.lower()
    return name == "auto" or name in {k.lower() for k in RESPONSE_METHODS}


def _rising_from_brightest(exposures: np.ndarray) -> list[int]:
    """Indices of the frames whose exposures fall strictly from the brightest frame down (each
    kept frame darker than the kept one after it), in order."""
    keep = [len(exposures) - 1]
    for k in range(len(exposures) - 2, -1, -1):
        if exposures[k] < exposures[keep[-1]]:
            keep.append(k)
    return keep[::-1]


def _frame_list(ks: Sequence[int]) -> str:
    return ", ".join(str(k) for k in ks)


def _affine_near(h: np.ndarray, shape: tuple[int, int]) -> np.ndarray:
    """The 2x3 affine matrix equal to the homography ``h`` to first order at the image centre
    (within a few pixels at the borders for a hand-held bracket's small perspective)."""
    m = np.asarray(h, np.float64) / float(h[2, 2])
    cy, cx = (shape[0] - 1) / 2.0, (shape[1] - 1) / 2.0
    s = m[2, 0] * cx + m[2, 1] * cy + 1.0
    u = (m[0, 0] * cx + m[0, 1] * cy + m[0, 2]) / s
    v = (m[1, 0] * cx + m[1, 1] * cy + m[1, 2]) / s
    jac = np.array(
        [
            [(m[0, 0] - u * m[2, 0]) / s, (m[0, 1] - u * m[2, 1]) / s],
            [(m[1, 0] - v * m[2, 0]) / s, (m[1, 1] - v * m[2, 1]) / s],
        ]
    )
    t = np.array([u, v]) - jac @ np.array([cx, cy])
    return np.hstack([jac, t[:, None]])


def _moved(
    registration: BracketRegistration, shift_px: float = 0.5, angle_deg: float = 0.05
) -> bool:
    """Whether any registered pair moved more than ``shift_px`` or turned ``angle_deg``."""
    return any(
        q.usable and (math.hypot(q.dx, q.dy) > shift_px or abs(q.angle_deg) > angle_deg)
        for q in registration.pairs
    )


# -- the stage graph ---------------------------------------------------------------------------
#
# Each stage below is a function ``(ctx, p, up) -> value``: ``ctx`` the bracket and what follows
# from it alone (fixed for a pipeline's life), ``p`` a view of the parameter fields the stage
# declares, ``up`` the values of the upstream stages it declares. Reading anything else raises
# (hdrcore.stage_graph.UndeclaredDependency), and the cache key is derived from the same
# declaration, so a stage cannot depend on what its key leaves out. ARCHITECTURE.md says how to
# add one.


def _lut(ctx: _Context, response: ResponseCurve | None) -> np.ndarray | None:
    return None if response is None else response.to_lut(ctx.bracket.max_level)


def _ratio_fit(ctx: _Context, p: PipelineParams, lut: np.ndarray | None) -> dict[str, Any]:
    """The keyword arguments of the histogram ratio fit (whole frames or overlap fields)."""
    fit: dict[str, Any] = dict(
        method=p.exposure_method,
        exposure_times=ctx.bracket.exif_exposures(),
        saturation=p.saturation,
        noise_floor=p.noise_floor,
        lut=lut,
    )
    if p.exposure_method == DEFAULT_EXPOSURE_METHOD:
        # The measured noise drives the ratio fit too (noise matching of the refined
        # estimator): the seed's protocol, 4 scenes x 3 seeds, tripod, histograms: median
        # error 0.023 % -> 0.0010 % at 12 bits, 0.033 % -> 0.026 % at 8 bits.
        fit["noise_sigma"] = ctx.noise().sigma
    if p.noise_sigma is not None:
        fit["noise_sigma"] = p.noise_sigma
    return fit


def _stage_exclusions(ctx: _Context, p: Any, up: Inputs) -> Any:
    return _exclusions(ctx, p)


def _stage_histograms(ctx: _Context, p: Any, up: Inputs) -> BracketHistograms:
    excluded = up.exclusions
    return bracket_histograms(
        [f.levels for f in ctx.bracket.frames],
        ctx.bracket.max_level,
        mask=None if excluded is None else ~excluded[1],
    )


def _response_fields(ctx: _Context) -> tuple[str, ...]:
    # Without exposure times the response stands on rough ratios measured with the exposure
    # method; with them it never reads the method (switching it re-fits only the ratios).
    return ("response", "exposure_method") if ctx.no_times else ("response",)


def _stage_response(ctx: _Context, p: Any, up: Inputs) -> ResponseCurve | None:
    return _response(ctx, p, up.histograms, up.exclusions)


def _stage_ratios(ctx: _Context, p: Any, up: Inputs) -> BracketExposureResult:
    if ctx.fixed_ratios is not None:
        return ctx.fixed_ratios  # a draft's: the full-resolution frames' (Pipeline(ratios=))
    return bracket_exposures_from_histograms(
        up.histograms, **_ratio_fit(ctx, p, _lut(ctx, up.response))
    )


def _stage_times_histogram(ctx: _Context, p: Any, up: Inputs) -> tuple[tuple[float, ...], str]:
    return _merge_times(ctx, up.ratios, p)


def _stage_registration_ratios(ctx: _Context, p: Any, up: Inputs) -> tuple[float, ...]:
    if p.hold_registration is not None:
        return p.hold_registration[1]
    if p.times == "exif":
        times = up.times_histogram[0]
        return tuple(times[k + 1] / times[k] for k in range(len(times) - 1))
    # Registration tolerates the few per cent that motion leaves in the whole-frame estimate,
    # not a wild ratio: those are replaced by EXIF or the median step.
    return tuple(snap_ratio(float(r)) for r in up.ratios.starting_ratios())


#: The grid the registration's starting ratios are snapped to, in stops: a saturation or
#: noise-floor step moves the whole-frame ratios by 0.01-0.1 % (real phone brackets), and the
#: registration re-ran for each (10-12 s). Measured on the real Xperia and Pixel 7 brackets,
#: ratios off by 0.5 % moved its transforms by at most 0.003 px at the frame corners (Xperia)
#: and 0.008 px (Pixel 7; 0.084 px on its dim darkest frame, the least constrained pair), so a
#: ratio is read to the nearest 1/64 stop (within 0.55 %).
RATIO_GRID_STOPS = 1.0 / 64


def snap_ratio(ratio: float, grid: float = RATIO_GRID_STOPS) -> float:
    """``ratio`` rounded to the nearest multiple of ``grid`` stops (non-finite or non-positive
    ratios as they are)."""
    if not (math.isfinite(ratio) and ratio > 0.0):
        return ratio
    return float(2.0 ** (round(math.log2(ratio) / grid) * grid))


def _held_inputs(held: Any, n_frames: int) -> tuple[tuple[float, float], tuple[float, ...]] | None:
    """``PipelineParams.hold_registration`` checked: two levels and a ratio per pair of the
    bracket's ``n_frames`` (as floats, so a key does not depend on how they were given)."""
    if held is None:
        return None
    try:
        levels, ratios = held
        levels = (float(levels[0]), float(levels[1]))
        ratios = tuple(float(r) for r in ratios)
        if len(held[0]) != 2:
            raise ValueError
    except (TypeError, ValueError, IndexError):
        raise ParameterError(
            "hold_registration must be a result's registration_inputs",
            expected="((saturation, noise floor), (a ratio per pair))",
            found=repr(held)[:80],
        ) from None
    if len(ratios) != n_frames - 1:
        raise ParameterError(
            "hold_registration holds another bracket's ratios",
            expected=f"{n_frames - 1} ratios",
            found=str(len(ratios)),
        )
    return levels, ratios


def _stage_registration_levels(ctx: _Context, p: Any, up: Inputs) -> tuple[float, float]:
    """The saturation level and noise floor the registration reads: the requested ones
    snapped to the bracket's quantile ladder (:mod:`hdrcore.registration.thresholds`), so a
    slider step that moves the registration's masks by fewer than 0.5 % of the samples keeps
    the registration's key; a held registration's (``hold_registration``)."""
    if p.hold_registration is not None:
        return p.hold_registration[0]
    return snap_levels(up.histograms.counts[:, 1], _level(p.saturation), _level(p.noise_floor))


class _RegistrationParams:
    """The registration's view of the parameters: its snapped saturation level and noise
    floor (:func:`_stage_registration_levels`), every other field the stage's own view."""

    def __init__(self, p: Any, levels: tuple[float, float]) -> None:
        self._p = p
        self.saturation, self.noise_floor = levels

    def __getattr__(self, name: str) -> Any:
        return getattr(self._p, name)


def _stage_registration(ctx: _Context, p: Any, up: Inputs) -> BracketRegistration | None:
    if ctx.fixed_registration is not None and p.align != "none":
        return ctx.fixed_registration
    params: Any = _RegistrationParams(p, up.registration_levels)
    return _register(ctx, params, _lut(ctx, up.response), up.registration_ratios)


def _stage_response_registered(ctx: _Context, p: Any, up: Inputs) -> ResponseCurve | None:
    # Hand-held: the response again, from the registered frames' common field of view.
    return _response_registered(ctx, p, up.registration, up.histograms, up.exclusions)


def _stage_response_used(ctx: _Context, p: Any, up: Inputs) -> tuple[ResponseCurve | None, bool]:
    """The response the stages after registration use, and whether it is the one recovered
    again from the registered frames (a recovered response of a moved bracket)."""
    response, registration = up.response, up.registration
    if (
        registration is not None
        and response is not None
        and _recovered(p.response)
        and _moved(registration)
    ):
        return up.response_registered, True
    return response, False


def _overlap_matrices(registration: BracketRegistration) -> tuple[np.ndarray, ...]:
    # The common field of view: a homography's affine part is within a few pixels of it at the
    # borders, which is all the overlap fields need.
    return tuple(
        np.asarray(q.matrix if q.matrix is not None else _affine_near(_pair_motion(q), q.shape))
        for q in registration.pairs
    )


def _stage_overlap_histograms(ctx: _Context, p: Any, up: Inputs) -> BracketHistograms:
    excluded = up.exclusions
    return bracket_histograms(
        [f.levels for f in ctx.bracket.frames],
        ctx.bracket.max_level,
        pair_matrices=_overlap_matrices(up.registration),
        mask=None if excluded is None else ~excluded[1],
    )


def _stage_overlap_ratios(ctx: _Context, p: Any, up: Inputs) -> BracketExposureResult:
    # Beyond the paper: with the geometry known, each pair is measured again over its common
    # field of view only, so content that the hand-held motion moved across the frame borders
    # no longer biases the ratios: from the registered pixels themselves (default,
    # hdrcore.exposure.registered) or from the histograms of that field.
    response, moved = up.response_used
    lut = _lut(ctx, response)
    if p.refine_ratios == "pixels":
        measured = _pixel_ratios(ctx, p, lut, up.registration, up.ratios, up.exclusions)
    else:
        measured = bracket_exposures_from_histograms(
            up.overlap_histograms, **_ratio_fit(ctx, p, lut)
        )
    # A response recovered from a moved bracket carries a model error of its own.
    return _with_response_error(measured, MOVED_RESPONSE_ERROR_PER_STOP) if moved else measured


def _stage_exposures(ctx: _Context, p: Any, up: Inputs) -> BracketExposureResult:
    """The ratios the merge uses: measured again over the pairs' common fields once the
    registration is known (``refine_ratios``), else the whole-frame estimate."""
    if up.registration is None or p.refine_ratios == "none":
        return up.ratios
    return up.overlap_ratios


def _stage_merge_times(ctx: _Context, p: Any, up: Inputs) -> tuple[tuple[float, ...], str]:
    return _merge_times(ctx, up.exposures, p)


def _stage_merge(ctx: _Context, p: Any, up: Inputs, reuse: Any = None) -> tuple:
    response, _ = up.response_used
    times, _ = up.merge_times
    # The region ghost test (no pixel changes without deghost) is left to the run, which does
    # it after the preview or leaves it to the caller (Pipeline.run(checks="later")); so are
    # the colour checks of a non-linear merge (they change no pixel either).
    lut = _lut(ctx, response)
    return _merge_frames(
        ctx,
        p,
        lut,
        times,
        up.reading,
        up.exclusions,
        reuse=reuse,
        defer_ghost_test=True,
        frame_measures=None if lut is None else up.frame_measures,
        colour_later=True,
    )


def _stage_reading(ctx: _Context, p: Any, up: Inputs) -> _Reading | None:
    registration = up.registration
    if registration is None:
        return None
    return _Reading(
        int(registration.reference),
        tuple(_read_in_place(registration, ctx.bracket.shape[:2])),
        registration.local,
    )


def _stage_frame_measures(ctx: _Context, p: Any, up: Inputs) -> FrameMeasures | None:
    """A non-linear bracket's white balance per frame and local tone mapping test, and what
    the colour checks measure on the frames alone: they read the frames, their response and
    motion, never the merge or its levels, so a saturation or noise-floor step takes them from
    the cache (0.35 s a step on the real Pixel 7 bracket, and the checks' frame side)."""
    response, _ = up.response_used
    lut = _lut(ctx, response)
    if lut is None:
        return None
    if ctx.fixed_frame_measures is not None:
        return ctx.fixed_frame_measures  # a draft's: the full frames' (Pipeline(frame_measures=))
    registration, excluded = up.reading, up.exclusions
    return measure_frames(
        [f.levels for f in ctx.bracket.frames],
        lut,
        max_level=ctx.bracket.max_level,
        reference=0 if registration is None else registration.reference,
        to_reference=None
        if registration is None
        else _read_in_place(registration, ctx.bracket.shape),
        masks=None if excluded is None else [~e for e in excluded[0]],
    )


def _stage_preview(ctx: _Context, p: Any, up: Inputs) -> tuple[TonemapResult, int]:
    _, radiance, colour_info, _ = up.merge
    ltm = colour_info.get("check", {}).get("local_tone_mapping") or {}
    if ltm.get("detected"):
        # the frames' exposure fusion: read from its own stage, kept while only the merge's
        # levels move (it reads the frames and their motion, never the merge)
        return up.fusion
    return _preview(ctx, p, radiance)


def _stage_fusion(ctx: _Context, p: Any, up: Inputs) -> tuple[TonemapResult, int]:
    """The preview of locally tone-mapped frames: their exposure fusion (Mertens et al.
    2007) at the preview's size. A function of the frames, their motion and the preview's
    size alone, so a saturation or noise-floor step (a new merge, the same motion) draws it
    from the cache: 2.0-2.6 s a step on the real Pixel 7 bracket."""
    return _fusion_preview(ctx, p, up.registration)


_SAT_NF = ("saturation", "noise_floor")

#: The registration's inputs it reads snapped (its levels to the bracket's ladder, its starting
#: ratios to 1/64 stop): a small move of the fields behind them keeps the motion, or moves it by
#: hundredths of a pixel (:mod:`hdrcore.registration.thresholds`, :data:`RATIO_GRID_STOPS`).
SNAPPED_INPUTS = ("registration_levels", "registration_ratios")

#: How many values of different parameters the slow stages with small values keep
#: (:attr:`hdrcore.stage_graph.Stage.keep`: the response, the ratios, the registration, the
#: response recovered on the registered pixels and the ratios measured on them, a few MB each
#: at 24 MP, and the exposure fusion of locally tone-mapped frames, an 8-bit preview): a
#: control moved back, or a reset, takes them again. On the real Pixel 7 bracket in the
#: inspector, going back to the default alignment after trying another re-registered and
#: fused its frames again: 13.5-18.4 s.
RECENT_VALUES = 4

#: The pipeline's stages: what each reads, in one place. The reported ones are :data:`STAGES`;
#: the internal ones are steps between them (the merge's times, the response the later stages
#: use) whose values the keys of later stages depend on.
GRAPH = StageGraph(
    [
        Stage("exclusions", _stage_exclusions, ("exclude_colour",), internal=True),
        Stage("histograms", _stage_histograms, (), ("exclusions",)),
        Stage(
            "response",
            _stage_response,
            _response_fields,
            ("histograms", "exclusions"),
            keep=RECENT_VALUES,
        ),
        Stage(
            "ratios",
            _stage_ratios,
            (*_SAT_NF, "exposure_method", "noise_sigma"),
            ("histograms", "response"),
            keep=RECENT_VALUES,
        ),
        Stage(
            "times_histogram",
            _stage_times_histogram,
            ("times", "ratio_fallback_stops"),
            ("ratios",),
            by_value=True,
            internal=True,
        ),
        Stage(
            "registration_ratios",
            _stage_registration_ratios,
            ("times", "hold_registration"),
            ("ratios", "times_histogram"),
            by_value=True,
            internal=True,
        ),
        Stage(
            "registration_levels",
            _stage_registration_levels,
            (*_SAT_NF, "hold_registration"),
            ("histograms",),
            by_value=True,
            internal=True,
        ),
        Stage(
            "registration",
            _stage_registration,
            (
                "threshold",
                "align",
                "reference",
                "registration_method",
                "registration_previews",
                "registration_max_pixels",
                "local",
            ),
            ("response", "registration_ratios", "registration_levels"),
            keep=RECENT_VALUES,
        ),
        Stage(
            "response_registered",
            _stage_response_registered,
            _response_fields,
            ("registration", "histograms", "exclusions"),
            keep=RECENT_VALUES,
        ),
        Stage(
            "response_used",
            _stage_response_used,
            ("response",),
            ("response", "registration"),
            lazy=("response_registered",),
            # by value: a registration that moves nothing leaves it as it was (_Reading)
            by_value=True,
            internal=True,
        ),
        Stage("overlap_histograms", _stage_overlap_histograms, (), ("registration", "exclusions")),
        Stage(
            "overlap_ratios",
            _stage_overlap_ratios,
            ("refine_ratios", *_SAT_NF, "exposure_method", "noise_sigma"),
            ("registration", "response_used", "ratios", "exclusions"),
            lazy=("overlap_histograms",),
            keep=RECENT_VALUES,
        ),
        Stage(
            "exposures",
            _stage_exposures,
            ("refine_ratios",),
            ("ratios", "registration"),
            lazy=("overlap_ratios",),
            internal=True,
        ),
        Stage(
            "merge_times",
            _stage_merge_times,
            ("times", "ratio_fallback_stops"),
            ("exposures",),
            by_value=True,
            internal=True,
        ),
        Stage("reading", _stage_reading, (), ("registration",), by_value=True, internal=True),
        Stage(
            "frame_measures",
            _stage_frame_measures,
            (),
            ("response_used", "reading", "exclusions"),
            internal=True,
        ),
        Stage(
            "merge",
            _stage_merge,
            (*_SAT_NF, "working_space", "deghost", "colour_anchor", "white_balance"),
            ("response_used", "reading", "merge_times", "exclusions"),
            lazy=("frame_measures",),
        ),
        Stage(
            "fusion",
            _stage_fusion,
            ("preview_max_side",),
            ("registration",),
            internal=True,
            keep=RECENT_VALUES,
        ),
        Stage(
            "preview",
            _stage_preview,
            ("tonemap", "tonemap_exposure", "preview_max_side"),
            ("merge",),
            lazy=("fusion",),
        ),
    ],
    param_fields=[f.name for f in dataclass_fields(PipelineParams)],
)

if set(STAGES) != {name for name, st in GRAPH.stages.items() if not st.internal}:
    raise RuntimeError("STAGES must list the graph's reported stages")


def run_pipeline(
    bracket: Bracket, params: PipelineParams | None = None, progress: ProgressCallback | None = None
) -> PipelineResult:
    """One-shot convenience: ``Pipeline(bracket, params, progress=progress).run()``."""
    return Pipeline(bracket, params, progress=progress).run()

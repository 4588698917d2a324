"""The inspector's link to ``hdrcore``: load a bracket, run the pipeline, keep the latest result.

This module is the only place in ``hdrview`` that calls the processing library; panels only draw
the objects it returns. ``Controls`` holds what the page's widgets say; ``Session.run`` turns it
into the pipeline's parameters and asks the pipeline to re-run what changed.
"""

from __future__ import annotations

import dataclasses
import importlib
import importlib.util
import logging
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

from hdrcore.io import Bracket, load_bracket

__all__ = ["Controls", "Session", "pipeline_available"]

log = logging.getLogger(__name__)


_PIPELINE_OK = False


def pipeline_available() -> bool:
    """True once ``hdrcore.pipeline`` imports and offers ``Pipeline`` and ``PipelineParams``."""
    global _PIPELINE_OK
    if _PIPELINE_OK:
        return True
    if importlib.util.find_spec("hdrcore.pipeline") is None:
        return False
    try:
        mod = importlib.import_module("hdrcore.pipeline")
    except ImportError:
        log.debug("hdrcore.pipeline is present but does not import yet", exc_info=True)
        return False
    _PIPELINE_OK = hasattr(mod, "Pipeline") and hasattr(mod, "PipelineParams")
    return _PIPELINE_OK


@dataclass(frozen=True)
class Controls:
    """The values of the page's parameter widgets (``None``: the pipeline's default)."""

    saturation: float | None = None
    noise_floor: float | None = None
    threshold: float | None = None
    alignment: str | None = None
    local: str | None = None
    reference: int | None = None
    response: str | None = None
    tonemap: str | None = None
    exposure: float | None = None
    deghost: bool | None = None
    times: str | None = None
    exposure_method: str | None = None

    def replace(self, **changes: Any) -> Controls:
        return dataclasses.replace(self, **changes)


# Names the pipeline's parameter object may use for each control, first match wins.
_PARAM_NAMES: dict[str, tuple[str, ...]] = {
    "saturation": ("saturation_level", "saturation"),
    "noise_floor": ("noise_floor",),
    "threshold": ("threshold", "normalisation_threshold", "threshold_t"),
    "alignment": ("alignment", "align", "alignment_model", "model"),
    "local": ("local",),
    "reference": ("reference", "reference_frame"),
    "response": ("response", "response_method"),
    "tonemap": ("tonemap", "tonemap_operator", "operator"),
    "exposure": ("exposure", "tonemap_exposure", "exposure_ev"),
    "deghost": ("deghost",),
    "times": ("times",),
    "exposure_method": ("exposure_method",),
}


@dataclass
class Session:
    """One loaded bracket, its pipeline and the latest result."""

    bracket: Bracket | None = None
    source: str = ""
    pipeline: Any = None
    result: Any = None
    params: Any = None
    timings: dict[str, float] = field(default_factory=dict)
    full_params: Any = None  # the parameters of the last run through every stage
    workers: int | None = None  # PipelineParams.workers of every run (hdrview --workers)

    def load(self, paths: Sequence[str | os.PathLike], *, source: str = "",
             times: str | os.PathLike | None = None,
             loader: Callable[..., Bracket] | None = None) -> Bracket:
        """Load these frame files (already checked by :class:`hdrview.security.RootResolver`,
        which also found the folder's exposure-times list, ``times``); ``loader(files, times)``
        decodes them (the inspector's shared :class:`hdrview.cache.BracketCache`)."""
        if loader is None:
            bracket = load_bracket(list(paths), exposure_times=times)
        else:
            bracket = loader(list(paths), times)
        self.bracket = bracket
        self.source = source or ", ".join(str(p) for p in paths)
        self.pipeline = None
        self.result = None
        self.params = None
        self.full_params = None
        return bracket

    # -- pipeline ---------------------------------------------------------------------------

    def default_params(self) -> Any:
        from hdrcore.pipeline import PipelineParams

        return PipelineParams(workers=self.workers)

    def params_for(self, controls: Controls) -> Any:
        """The pipeline's defaults with every control that is set (a reset control goes back to
        the default, never to its previous value)."""
        base = self.default_params()  # a control left at None means the pipeline's default
        names = {f.name for f in dataclasses.fields(base)}
        changes = {}
        for key, candidates in _PARAM_NAMES.items():
            value = getattr(controls, key)
            if value is None:
                continue
            for cand in candidates:
                if cand in names:
                    changes[cand] = value
                    break
        return dataclasses.replace(base, **changes)

    def param_value(self, control: str) -> Any:
        """Current pipeline value behind a control (for the widgets' initial values)."""
        params = self.params if self.params is not None else self.default_params()
        for cand in _PARAM_NAMES[control]:
            if hasattr(params, cand):
                return getattr(params, cand)
        return None

    def run(self, controls: Controls, progress: Callable[..., None] | None = None,
            until: str | None = None) -> Any:
        """Run (or re-run what changed in) the pipeline; return its result object."""
        if self.bracket is None:
            return None
        from hdrcore.pipeline import Pipeline

        params = self.params_for(controls)
        if self.pipeline is None:
            self.pipeline = Pipeline(self.bracket, params, progress=progress)
        elif progress is not None and hasattr(self.pipeline, "progress"):
            self.pipeline.progress = progress
        result = self.pipeline.run(params) if until is None else self.pipeline.run(
            params, until=until)
        self.params = params
        self.result = result
        if until is None:
            self.full_params = params
        return result

    def draft_wanted(self, controls: Controls, max_side: int | None = None,
                     min_factor: int = 2) -> bool:
        """Whether a draft (:mod:`hdrcore.draft`) shows anything sooner: the bracket is at least
        ``min_factor`` times the draft's size (longer side ``max_side``) and a parameter the
        merge reads changed since the last full run (the operator and the exposure re-run the
        preview only)."""
        if self.bracket is None:
            return False
        from hdrcore.draft import DRAFT_MAX_SIDE, draft_factor

        if draft_factor(self.bracket.shape, max_side or DRAFT_MAX_SIDE) < min_factor:
            return False
        if self.full_params is None:
            return True
        preview_only = ("tonemap", "tonemap_exposure")
        new = dataclasses.replace(self.params_for(controls),
                                  **{k: getattr(self.full_params, k) for k in preview_only})
        return new != self.full_params

    def run_draft(self, quick: Any, progress: Callable[..., None] | None = None,
                  max_side: int | None = None) -> Any:
        """The draft of the preview (:func:`hdrcore.draft.run_draft`) for the parameters of
        ``quick``, a run until the ratios (its saturation and noise floor): with the response
        and exposure times the last full run ended with (a hand-held bracket's response is
        recovered again after registration, its ratios measured on the registered pixels;
        the response only when its control is unchanged), else those of ``quick``."""
        from hdrcore.draft import DRAFT_MAX_SIDE, run_draft

        p = quick.params
        last = self.pipeline.last_result if self.pipeline is not None else None
        curve, times = quick.response, quick.exposure_times
        if (last is not None and self.full_params is not None and last.until == "preview"
                and self.full_params.response == p.response and last.response is not None):
            curve = last.response
        if (last is not None and self.full_params is not None and last.until == "preview"
                and len(last.exposure_times) == len(self.bracket)):
            times = last.exposure_times  # measured on the registered pixels
        if len(times) != len(self.bracket):
            times = None  # a run without unusable frames: the draft measures its own
        if curve is not None:
            p = p.replace(response=curve)
        return run_draft(self.bracket, p, progress=progress, exposure_times=times,
                         max_side=max_side or DRAFT_MAX_SIDE)

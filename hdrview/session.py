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
        return bracket

    # -- pipeline ---------------------------------------------------------------------------

    def default_params(self) -> Any:
        from hdrcore.pipeline import PipelineParams

        return PipelineParams()

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
        return result

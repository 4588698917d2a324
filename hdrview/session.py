"""The inspector's link to ``hdrcore``: load a bracket, run the pipeline, keep the latest result.

This module is the only place in ``hdrview`` that calls the processing library; panels only draw
the objects it returns. ``Controls`` holds what the page's widgets say; ``Session.run`` turns it
into the pipeline's parameters and asks the pipeline to re-run what changed.
"""

from __future__ import annotations

import dataclasses
import os
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hdrcore.errors import InputError
from hdrcore.io import Bracket, load_bracket

if TYPE_CHECKING:  # imported on first use (slow: numba), not with the page
    from hdrcore.pipeline import Pipeline, PipelineParams, PipelineResult, ProgressCallback
    from hdrcore.registration import BracketRegistration

__all__ = ["MOTION_FIELDS", "Controls", "Session", "pipeline_available"]

#: The parameters that choose the kind of motion a registration finds: a draft after a change
#: of one of them registers its binned frames (:meth:`Session.draft_motion`). The
#: registration's other parameters (threshold t, local refinement, its overlays) and the
#: snapped saturation and noise floor it reads choose only its pixels, or add what the draft
#: leaves out.
MOTION_FIELDS = ("align", "reference", "registration_method", "registration_max_pixels")


def pipeline_available() -> bool:
    """Import ``hdrcore.pipeline`` (its compiled kernels take a second or two to load), so that
    a caller can do it off the thread that serves pages; True once it is imported."""
    import hdrcore.pipeline  # noqa: F401

    return True


@dataclass(frozen=True)
class Controls:
    """The values of the page's parameter widgets (``None``: the pipeline's default). Each
    field is the :class:`hdrcore.pipeline.PipelineParams` field of the same name."""

    saturation: float | None = None
    noise_floor: float | None = None
    threshold: float | None = None
    align: str | None = None
    local: str | None = None
    reference: int | None = None
    response: str | None = None
    tonemap: str | None = None
    tonemap_exposure: float | None = None
    deghost: bool | None = None
    white_balance: bool | None = None
    times: str | None = None
    exposure_method: str | None = None

    def replace(self, **changes: Any) -> Controls:
        return dataclasses.replace(self, **changes)

    def changes(self) -> dict[str, Any]:
        """The controls that are set, by parameter name."""
        return {
            f.name: v for f in dataclasses.fields(self) if (v := getattr(self, f.name)) is not None
        }


@dataclass
class Session:
    """One loaded bracket, its pipeline and the latest result."""

    bracket: Bracket | None = None
    source: str = ""
    pipeline: Pipeline | None = None
    result: PipelineResult | None = None
    params: PipelineParams | None = None
    timings: dict[str, float] = field(default_factory=dict)
    full_params: PipelineParams | None = None  # the parameters of the last run to the end
    workers: int | None = None  # PipelineParams.workers of every run (hdrview --workers)
    # the drafts' binned frames kept across slider steps (hdrcore.draft.DraftCache, made by the
    # first draft of a bracket), and which registration the last draft used
    draft_cache: Any = None
    draft_registration: str = ""

    def load(
        self,
        paths: Sequence[str | os.PathLike],
        *,
        source: str = "",
        times: str | os.PathLike | None = None,
        loader: Callable[[list[str | os.PathLike[str]], str | os.PathLike[str] | None], Bracket]
        | None = None,
    ) -> Bracket:
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
        self.draft_cache = None
        self.draft_registration = ""
        return bracket

    # -- pipeline ---------------------------------------------------------------------------

    def default_params(self) -> PipelineParams:
        from hdrcore.pipeline import PipelineParams

        return PipelineParams(workers=self.workers)

    def params_for(self, controls: Controls) -> PipelineParams:
        """The pipeline's defaults with every control that is set (a reset control goes back to
        the default, never to its previous value)."""
        return self.default_params().replace(**controls.changes())

    def run(
        self,
        controls: Controls,
        progress: ProgressCallback | None = None,
        until: str | None = None,
        checks: str = "now",
    ) -> PipelineResult:
        """Run (or re-run what changed in) the pipeline; return its result. ``checks="later"``:
        the merge comes back before the measurements that change no pixel, its region ghost
        test and colour checks (:meth:`finish_checks` makes them)."""
        if self.bracket is None:
            raise InputError("no bracket loaded: load one first")
        from hdrcore.pipeline import Pipeline

        params = self.params_for(controls)
        if self.pipeline is None:
            # the sliders register the same frames again and again
            self.pipeline = Pipeline(
                self.bracket, params, progress=progress, keep_registration_inputs=True
            )
        elif progress is not None:
            self.pipeline.progress = progress
        result = self.pipeline.run(params, until=until or "preview", checks=checks)
        self.params = params
        self.result = result
        if until is None:
            self.full_params = params
        return result

    def finish_checks(self, result: PipelineResult) -> PipelineResult:
        """``result`` with the measurements it left for later made (its merge's region ghost
        test, its colour checks; the verdicts that read them too); itself when none is
        pending."""
        if self.pipeline is None:
            return result
        done = self.pipeline.finish_checks(result)
        if self.result is result:
            self.result = done
        return done

    def draft_wanted(
        self, controls: Controls, max_side: int | None = None, min_factor: int = 2
    ) -> bool:
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
        new = dataclasses.replace(
            self.params_for(controls), **{k: getattr(self.full_params, k) for k in preview_only}
        )
        if new == self.full_params:
            return False
        from hdrcore.merge.fusion import METHOD as FUSION
        from hdrcore.pipeline import SNAPPED_INPUTS

        last = self._last_full_run()
        # A draft takes the last full run's motion when the kind of motion is unchanged
        # (draft_motion): what only the registration reads (threshold t, local refinement)
        # then changes nothing in its picture. A threshold step drew the last picture again,
        # binned: 0.5-0.65 s before the re-registration on the 24 MP sRGB bench bracket.
        kept = last is not None and self._motion(last, new, self.full_params) is not None
        motion = ("registration",) if kept else ()
        assert self.pipeline is not None  # a full run was made
        if last is not None and last.preview is not None and last.preview.method == FUSION:
            # Locally tone-mapped frames: the preview is their exposure fusion, which reads
            # the frames and their motion, not the merge's levels or colour: a step of these
            # (or of the fields the registration reads snapped) leaves the picture as it is (a
            # draft of it cost 2.5-3.2 s a step on the real Pixel 7 bracket and showed the same
            # picture, binned).
            read = self.pipeline.fields_read("fusion", skip=SNAPPED_INPUTS + motion)
        elif kept:
            read = self.pipeline.fields_read("preview", skip=motion)
        else:
            return True
        return any(getattr(new, k) != getattr(self.full_params, k) for k in read)

    def _last_full_run(self) -> PipelineResult | None:
        """The pipeline's last run to the end (the preview), when there was one."""
        last = self.pipeline.last_result if self.pipeline is not None else None
        if last is None or self.full_params is None or last.until != "preview":
            return None
        return last

    def interim_params(self, quick: PipelineResult) -> PipelineParams | None:
        """The parameters of ``quick`` (a run until the ratios) with the last full run's
        registration held (``PipelineParams.hold_registration``), when the step registers the
        frames again only because what the registration reads snapped moved (a saturation or
        noise-floor step across a rung of the bracket's ladder, :data:`SNAPPED_INPUTS`) and
        that run's motion is the one a draft would take (:meth:`draft_motion`); else
        ``None``. The full-resolution merge of these parameters is the new picture within a
        re-merge's time, instead of after the registration (8-11 s on the real phone
        brackets); the motion it holds moves by hundredths of a pixel for such a step."""
        last = self._last_full_run()
        if (
            self.pipeline is None
            or last is None
            or last.registration_inputs is None
            or quick.registration_inputs is None
            or quick.registration_inputs == last.registration_inputs
            or self.draft_motion(quick) is None
        ):
            return None
        if self.pipeline.registration_cached(quick.params):
            return None  # registered already (a value tried before): nothing to wait for
        held = quick.params.replace(hold_registration=last.registration_inputs)
        # (another field the registration reads changed too, a reset: it would register)
        return held if self.pipeline.registration_cached(held) else None

    def run_interim(
        self, params: PipelineParams, progress: ProgressCallback | None = None
    ) -> PipelineResult:
        """The full run of :meth:`interim_params`'s parameters, checks left for later (the
        picture only; neither the session's result nor its parameters change)."""
        assert self.pipeline is not None  # interim_params found a full run
        if progress is not None:
            self.pipeline.progress = progress
        return self.pipeline.run(params, checks="later")

    def draft_motion(self, quick: PipelineResult) -> BracketRegistration | None:
        """The last full run's registration, for a draft with the parameters of ``quick``, when
        it is that run's motion of the whole loaded bracket and the parameters that choose the
        kind of motion (:data:`MOTION_FIELDS`: the model, the reference frame, the method, the
        registration's resolution) and the response are unchanged; else ``None`` (the draft
        registers its binned frames).

        A saturation, noise-floor or threshold-t step changes only which pixels the
        registration reads; the full run may register again, and the motion it finds is
        nearer the last one than the binned frames' own registration is. Measured at the
        frame corners, full-resolution pixels, median over pairs (worst pair), for steps of
        saturation -1 level and -5 %, noise floor +5, t = 0.05 and 0.2: the 24 MP bench
        bracket 0.000-0.015 (0.018) against 0.036-0.35 (0.55); Xperia 0.000-0.040 (0.45)
        against 0.19-0.29 (1.76); Pixel 7 0.008-0.28 (4.4, a pair that changed model) against
        0.70-0.88 (5.9). The last full run's motion is the better draft until the new one is
        known, and it costs nothing (registering the binned frames: 0.47 s at 24 MP)."""
        last = self._last_full_run()
        if last is None or self.full_params is None:
            return None
        return self._motion(last, quick.params, last.params)

    def _motion(
        self, last: PipelineResult, p: PipelineParams, before: PipelineParams | None
    ) -> BracketRegistration | None:
        """``last``'s registration when a draft with parameters ``p`` takes it: it is the
        motion of the whole loaded bracket and ``p`` has the :data:`MOTION_FIELDS` of
        ``before`` (parameters in the same form: both checked, or both as the controls give
        them) and the response of the last full run; else ``None``."""
        bracket = self.bracket
        full = self.full_params
        if (
            full is None
            or before is None
            or bracket is None
            or last.bracket is not bracket  # frames left out: pairs of a sub-bracket
            or last.registration is None
            or len(last.registration.pairs) != len(bracket) - 1
        ):
            return None
        if any(getattr(p, f) != getattr(before, f) for f in MOTION_FIELDS):
            return None
        if full.response != p.response:
            return None  # the registration reads the response
        return last.registration

    def run_draft(
        self,
        quick: PipelineResult,
        progress: ProgressCallback | None = None,
        max_side: int | None = None,
    ) -> PipelineResult:
        """The draft of the preview (:func:`hdrcore.draft.run_draft`) for the parameters of
        ``quick``, a run until the ratios (its saturation and noise floor): with the response
        and exposure times the last full run ended with (a hand-held bracket's response is
        recovered again after registration, its ratios measured on the registered pixels;
        the response only when its control is unchanged), else those of ``quick``."""
        from hdrcore.draft import DRAFT_MAX_SIDE, DraftCache, run_draft

        bracket = self.bracket
        assert bracket is not None  # quick is a run of the loaded bracket
        p = quick.params
        last = self._last_full_run()
        curve = quick.response
        times: tuple[float, ...] | None = quick.exposure_times
        if (
            last is not None
            and self.full_params is not None
            and self.full_params.response == p.response
            and last.response is not None
        ):
            curve = last.response
        if last is not None and len(last.exposure_times) == len(bracket):
            times = last.exposure_times  # measured on the registered pixels
        if times is not None and len(times) != len(bracket):
            times = None  # a run without unusable frames: the draft measures its own
        # merged with those times, the draft only reports its whole-frame ratios: the full
        # frames' of the same parameters (quick's) stand in for its own fit
        ratios = quick.exposures if quick.bracket is bracket else None
        # and with the last full run's motion and response, that run's white balance per frame
        # and local tone mapping test (measured on the full frames)
        motion = self.draft_motion(quick)
        measures = (
            last.frame_measures
            if last is not None
            and motion is not None
            and curve is last.response
            and p.exclude_colour == last.params.exclude_colour
            else None
        )
        if curve is not None:
            p = p.replace(response=curve)
        if self.draft_cache is None:
            self.draft_cache = DraftCache()
        draft = run_draft(
            bracket,
            p,
            progress=progress,
            exposure_times=times,
            max_side=max_side or DRAFT_MAX_SIDE,
            registration=motion,
            cache=self.draft_cache,
            ratios=ratios,
            frame_measures=measures,
        )
        self.draft_registration = (
            "none"
            if draft.registration is None
            else "the full run's, scaled"
            if motion is not None
            else "its own, of the binned frames"
        )
        return draft

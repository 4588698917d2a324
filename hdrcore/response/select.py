"""``--response auto``: the response chosen on evidence, with a safe fallback.

Candidates (issue 15, "pick the method on evidence"):

* ``joint-histogram`` -- the joint non-parametric recovery (:mod:`.joint`), or
  ``joint-pixels`` when the frames are registered (sampled on one grid);
* the parametric families of :mod:`.parametric` (``gamma``, ``srgb-toe``, ``filmic``), fitted
  to the same correspondences;
* ``srgb`` -- plain IEC 61966-2-1 decoding, which needs no fit.

Each fitted candidate is fitted on one fold of the chess board of image regions
(:func:`.holdout.fold_masks`) and scored on the other, both ways; the score is the weighted RMS
residual of the held-back level pairs in log exposure (:func:`.holdout.heldout_residual`,
one free ratio per pair, shared by the channels, expressed on the scale of the given exposure
ratios so the exponential ambiguity ``g -> g^gamma`` earns nothing). The recovered curve is
then checked for degeneracy (:mod:`.degeneracy`) on the whole bracket. The winner is the
lowest score among the curves that are not degenerate, except that a curve must beat plain
sRGB by :data:`SRGB_MARGIN` to replace it: most JPEGs are sRGB-encoded, and a curve that
explains the data only as well as sRGB does not earn a departure from the colours the frames
show on a screen. A degenerate recovery falls back to the best of sRGB and the families, with
a warning in the curve's message and status (``"fallback"``). Radiometry first, colour second:
only the candidates within :data:`SCORE_TOLERANCE` of the best sound score are credible, and
among them a curve that gives pixels colours more than :data:`COLOUR_TOLERANCE` less consistent
between consecutive frames than the most consistent one is left out (the recovered curve is
then degenerate, ``colours-inconsistent``).

The winner is returned as a :class:`~hdrcore.response.curve.ResponseCurve` whose
``selection`` (a :class:`ResponseSelection`) holds every candidate's score, the margin, the
fallback and the reasons.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from typing import Any

import numpy as np

from ..errors import EstimationError, ParameterError
from ..histogram import histograms
from .curve import ResponseCurve
from .degeneracy import Degeneracy, degeneracy
from .holdout import (
    colour_consistency,
    colour_pairs,
    fold_masks,
    pair_residuals,
    sample_levels,
)
from .joint import (
    DEFAULT_SMOOTHING,
    JOINT_MODELS,
    SEPARATE_GAIN,
    checked_mask,
    fit_joint,
    fold_mask,
    level_residuals,
)
from .parametric import FAMILIES, fit_family
from .samples import (
    btf_pairs,
    check_bracket,
    consecutive_ratios,
    pixel_pairs,
    pixel_samples,
    valid_range,
)

__all__ = [
    "COLOUR_TOLERANCE",
    "SCORE_TOLERANCE",
    "SRGB_MARGIN",
    "CandidateScore",
    "ResponseSelection",
    "select_response",
]

#: A curve must explain held-back pairs this much better than sRGB (relative) to replace it.
SRGB_MARGIN = 0.15

#: A curve that gives pixels colours this much less consistent between frames than the most
#: consistent credible candidate (relative, :func:`.holdout.colour_consistency`) is not used.
COLOUR_TOLERANCE = 0.20

#: A candidate explaining held-back pairs more than this much worse (relative) than the best
#: candidate that is not degenerate is not credible as radiometry: it is not used, and colour
#: consistency is weighed only among the credible ones. The colour is the anchoring's to fix
#: (the frames' own colours, keeping the merge's luminance), the radiometry is not: on the
#: Pixel 7 bracket the filmic curve gave the most consistent colours (0.0120 against the
#: recovered curve's 0.0157) with a held-back error of 13.2 % against 4.9 %, and one grey wall
#: read 3.25 to 0.73 from the darkest to the brightest frame (the recovered curve: 7.9 to 5.8,
#: frames 2-4 within 1 %), so wherever a frame's weight fades (the hand-held edges) the merge
#: jumped by up to 30 %.
SCORE_TOLERANCE = 0.25


def _less_consistent(value: float, reference: float, tolerance: float) -> bool:
    return bool(
        np.isfinite(value) and np.isfinite(reference) and value > (1.0 + tolerance) * reference
    )


@dataclass(frozen=True)
class CandidateScore:
    """One candidate of the selection: its held-back residual (ln units, NaN: not scored),
    the pairs behind it, per channel residuals, what it is, why it was left out, and
    ``colour``: the median chromaticity difference it leaves between consecutive frames
    (:func:`.holdout.colour_consistency`)."""

    name: str
    score: float
    per_channel: tuple[float, ...] = ()
    n_pairs: int = 0
    description: str = ""
    degenerate: tuple[Degeneracy, ...] = ()
    excluded: str = ""
    colour: float = float("nan")

    def to_json(self) -> dict[str, Any]:
        return {
            "name": self.name,
            "colour_consistency": None if not np.isfinite(self.colour) else float(self.colour),
            "score": None if not np.isfinite(self.score) else float(self.score),
            "per_channel": [None if not np.isfinite(v) else float(v) for v in self.per_channel],
            "n_pairs": int(self.n_pairs),
            "description": self.description,
            "degenerate": [d.to_json() for d in self.degenerate],
            "excluded": self.excluded,
        }


@dataclass(frozen=True)
class ResponseSelection:
    """The outcome of ``--response auto``.

    ``chosen`` won among ``candidates`` (sorted best first); ``runner_up`` is the next best
    and ``margin`` how much better the winner explains held-back pairs (relative: 0.2 = 20 %
    smaller residual). ``fallback`` is ``True`` when the recovered curve was degenerate and a
    safe curve took its place; ``recovered`` names the recovered candidate and ``degenerate``
    its signs of degeneracy. ``source`` says where the correspondences came from
    (``"histograms"`` or ``"pixels"``). ``message`` is one sentence for a report.
    ``curves[name]`` is every candidate's ``g`` ``(C, L)`` fitted on the whole bracket (the
    recovered one too when it was degenerate: draw it beside its fallback) and
    ``residuals[name]`` its weighted mean residual of ``ln g`` at every level
    (:func:`.joint.level_residuals`, NaN where no pair touches a level).
    """

    chosen: str
    candidates: tuple[CandidateScore, ...]
    runner_up: str | None
    margin: float
    fallback: bool
    recovered: str
    degenerate: tuple[Degeneracy, ...]
    source: str
    message: str
    parameters: dict[str, Any] = field(default_factory=dict)
    curves: dict[str, np.ndarray] = field(default_factory=dict, repr=False)
    residuals: dict[str, np.ndarray] = field(default_factory=dict, repr=False)

    def score(self, name: str) -> float:
        for c in self.candidates:
            if c.name == name:
                return c.score
        return float("nan")

    def to_json(self) -> dict[str, Any]:
        return {
            "chosen": self.chosen,
            "runner_up": self.runner_up,
            "margin": None if not np.isfinite(self.margin) else float(self.margin),
            "fallback": bool(self.fallback),
            "recovered": self.recovered,
            "degenerate": [d.to_json() for d in self.degenerate],
            "source": self.source,
            "message": self.message,
            "candidates": [c.to_json() for c in self.candidates],
            "curves": {k: np.asarray(v, float).tolist() for k, v in self.curves.items()},
            "residuals": {
                k: [
                    [None if not np.isfinite(x) else float(x) for x in row]
                    for row in np.asarray(v, float)
                ]
                for k, v in self.residuals.items()
            },
        }


def _score(
    g: np.ndarray, pairs, lo: float, hi: float, log_ratios: np.ndarray
) -> tuple[float, tuple[float, ...], float, int]:
    """Held-back residual of ``g`` with free shared ratios, on the given ratios' scale:
    ``(score, per channel, squared weight, pairs)``."""
    res, weights, rho = pair_residuals(g, pairs, lo, hi, None)
    den = sum(float(np.sum(w**2)) for w in weights)
    if den <= 0:
        return float("inf"), (), 0.0, 0
    # the curve's own exposure scale: its fitted ratios against the given ones
    rw = np.zeros(rho.size)
    for w, corr in zip(weights, pairs, strict=True):
        np.add.at(rw, corr.pair, w**2)
    fitted = float(np.sqrt(np.sum(rw * rho**2) / max(np.sum(rw), 1e-300)))
    given = float(np.sqrt(np.sum(rw * log_ratios[: rho.size] ** 2) / max(np.sum(rw), 1e-300)))
    scale = given / fitted if fitted > 0 else 1.0
    per = tuple(
        float(np.sqrt(np.sum(w**2 * r**2) / np.sum(w**2))) * scale
        if np.sum(w**2) > 0
        else float("nan")
        for r, w in zip(res, weights, strict=True)
    )
    num = sum(float(np.sum(w**2 * r**2)) for r, w in zip(res, weights, strict=True))
    n = sum(int(np.count_nonzero(w)) for w in weights)
    return float(np.sqrt(num / den)) * scale, per, den, n


def select_response(
    frames: Sequence[np.ndarray],
    exposure_times: Sequence[float] | None,
    *,
    max_level: int | None = None,
    cutoff: float = 0.98,
    low_cut: float = 0.0,
    mask: np.ndarray | None = None,
    source: str = "histograms",
    smoothing: float = DEFAULT_SMOOTHING,
    families: Sequence[str] = tuple(FAMILIES),
    stride: int = 1,
    n_samples: int = 4000,
    seed: int = 0,
) -> ResponseCurve:
    """Choose the response of a bracket on held-back correspondences (see the module).

    ``source="pixels"`` takes the correspondences from sampled pixels of registered frames
    (the pipeline passes frames resampled on the reference grid), ``"histograms"`` from the
    brightness transfer functions (no registration needed).
    """
    from . import srgb_response

    frames, max_level = check_bracket(frames, max_level)
    ratios = consecutive_ratios(exposure_times, len(frames), required=True, method="auto response")
    if source not in ("histograms", "pixels"):
        raise ParameterError(
            f"unknown correspondence source {source!r}", expected="'histograms' or 'pixels'"
        )
    unknown = [f for f in families if f not in FAMILIES]
    if unknown:
        raise ParameterError(
            f"unknown response family {unknown[0]!r}", expected=f"some of {', '.join(FAMILIES)}"
        )
    log_r = np.log(np.asarray(ratios))
    lo, hi = valid_range(max_level, cutoff, low_cut)
    n_ch = frames[0].shape[2]
    h, w = frames[0].shape[:2]
    base = checked_mask(mask, (h, w))

    def make_pairs(fold):
        m = fold_mask(base, fold, (h, w))
        if source == "pixels":
            return [
                pixel_pairs(
                    pixel_samples(frames, c, max_level, n_samples=n_samples, mask=m, seed=seed),
                    lo,
                    hi,
                )
                for c in range(n_ch)
            ]
        # every channel of a frame counted in one pass (the frames are interleaved)
        counted = [histograms(np.asarray(f), max_level, m, stride=stride) for f in frames]
        return [
            btf_pairs(
                frames, c, max_level, lo, hi, mask=m, stride=stride, hists=[h[c] for h in counted]
            )
            for c in range(n_ch)
        ]

    recovered = "joint-histogram" if source == "histograms" else "joint-pixels"
    all_pairs = make_pairs(None)
    folds = [make_pairs(f) for f in fold_masks(2)]
    fit_kw: dict[str, Any] = dict(smoothing=smoothing, cutoff=cutoff, low_cut=low_cut)
    models = list(JOINT_MODELS) if n_ch > 1 else ["shared"]

    # --- held-back scores: fit on one fold, score on the other, pool -------------------------
    def fitted(name: str, pairs) -> np.ndarray:
        if name in models:
            return fit_joint(pairs, log_r, max_level, model=name, residuals=False, **fit_kw).g
        return fit_family(name, pairs, log_r, max_level, lo, hi, n_channels=n_ch).g

    pooled: dict[str, list[tuple[float, tuple[float, ...], float, int]] | None] = {}
    for name in [*models, *families]:
        acc: list[tuple[float, tuple[float, ...], float, int]] = []
        for i in range(2):
            try:
                g = fitted(name, folds[i])
            except (EstimationError, ParameterError):
                break
            acc.append(_score(g, folds[1 - i], lo, hi, log_r))
        pooled[name] = acc if len(acc) == 2 else None

    def pool(parts) -> tuple[float, tuple[float, ...], int]:
        if not parts:
            return float("inf"), (), 0
        den = sum(p[2] for p in parts)
        if den <= 0:
            return float("inf"), (), 0
        s = float(np.sqrt(sum(p[0] ** 2 * p[2] for p in parts) / den))
        per = tuple(
            float(np.sqrt(np.mean([p[1][c] ** 2 for p in parts if p[1]]))) for c in range(n_ch)
        )
        return s, per, sum(p[3] for p in parts)

    srgb = srgb_response(max_level, n_ch)
    srgb_parts = [_score(srgb.g, folds[i], lo, hi, log_r) for i in range(2)]

    # the curves fitted on the whole bracket, and how well each gives a pixel one colour in
    # consecutive frames (the frames' own pixels: the colour evidence)
    sampled = sample_levels(frames, base)
    full_fits = {}
    for m in models:
        try:
            full_fits[m] = fit_joint(all_pairs, log_r, max_level, model=m, **fit_kw)
        except EstimationError:
            pooled[m] = None
    if not full_fits:
        raise EstimationError("no channel model of the joint response could be fitted")
    family_curves: dict[str, ResponseCurve] = {}
    for fam in families:
        if pooled[fam]:
            try:
                family_curves[fam] = fit_family(
                    fam, all_pairs, log_r, max_level, lo, hi, n_channels=n_ch
                )
            except ParameterError:
                pooled[fam] = None
    made: dict[int, list] = {}  # the pixels compared, per curve length: made once

    def consistency(g: np.ndarray) -> float:
        m = np.atleast_2d(np.asarray(g)).shape[1] - 1
        if m not in made:
            made[m] = colour_pairs(sampled, m)
        return colour_consistency(g, sampled, pairs=made[m])

    colour = {m: consistency(f.g) for m, f in full_fits.items()}
    colour.update({fam: consistency(c.g) for fam, c in family_curves.items()})
    colour["srgb"] = consistency(srgb.g)

    # the channel model: the simplest unless a richer one explains held-back pairs better by
    # SEPARATE_GAIN without giving pixels less consistent colours
    model_scores = {m: pool(pooled[m])[0] if pooled[m] else float("inf") for m in models}
    chosen_model = next(m for m in models if m in full_fits)
    for m in models[1:]:
        if (
            m in full_fits
            and model_scores[m] < (1.0 - SEPARATE_GAIN) * model_scores[chosen_model]
            and not _less_consistent(colour[m], colour[chosen_model], 0.05)
        ):
            chosen_model = m
    full = full_fits[chosen_model]
    colour[recovered] = colour[chosen_model]
    signs = tuple(
        degeneracy(
            full.g,
            data_range=full.data_range,
            active=full.active,
            n_nodes=full.nodes.size,
            channels_fitted_apart=False,
        )
    )

    cands: list[CandidateScore] = []
    s, per, n = pool(pooled[chosen_model]) if pooled[chosen_model] else (float("inf"), (), 0)
    text = ", ".join(f"{m} {100 * v:.2f} %" for m, v in model_scores.items())
    cands.append(
        CandidateScore(
            recovered,
            s,
            per,
            n,
            f"joint recovery, channel model {chosen_model} ({text})",
            signs,
            colour=colour[recovered],
        )
    )
    for fam in families:
        s, per, n = pool(pooled[fam]) if pooled[fam] else (float("inf"), (), 0)
        cands.append(
            CandidateScore(
                fam, s, per, n, FAMILIES[fam].description, colour=colour.get(fam, float("nan"))
            )
        )
    s, per, n = pool(srgb_parts)
    cands.append(
        CandidateScore("srgb", s, per, n, "sRGB decoding (IEC 61966-2-1)", colour=colour["srgb"])
    )

    srgb_score = cands[-1].score
    # the radiometrically credible candidates: within SCORE_TOLERANCE of the best held-back
    # score among those not degenerate (the recovered curve's signs so far: binding, flat,
    # channels; one worse than sRGB by SRGB_MARGIN, flagged below, is never that best)
    sound = [c for c in cands if np.isfinite(c.score) and not (c.name == recovered and signs)]
    best_sound = min(sound, key=lambda c: c.score) if sound else None

    def credible(c: CandidateScore) -> bool:
        return bool(
            np.isfinite(c.score)
            and (best_sound is None or c.score <= (1.0 + SCORE_TOLERANCE) * best_sound.score)
        )

    finite_colours = [c.colour for c in cands if np.isfinite(c.colour) and credible(c)]
    best_colour = min(finite_colours) if finite_colours else float("nan")
    best_by_colour = next((c.name for c in cands if c.colour == best_colour and credible(c)), "")
    if np.isfinite(srgb_score) and cands[0].score > (1.0 + SRGB_MARGIN) * srgb_score:
        signs = (
            *signs,
            Degeneracy(
                "worse-than-srgb",
                f"the recovered curve explains held-back pairs worse than "
                f"sRGB ({100 * cands[0].score:.2f} % against {100 * srgb_score:.2f} %)",
                None,
                cands[0].score,
            ),
        )
    if credible(cands[0]) and _less_consistent(cands[0].colour, best_colour, COLOUR_TOLERANCE):
        signs = (
            *signs,
            Degeneracy(
                "colours-inconsistent",
                f"the recovered curve gives a pixel different colours in "
                f"consecutive frames (median chromaticity difference {cands[0].colour:.4f}, "
                f"{best_by_colour} {best_colour:.4f})",
                None,
                cands[0].colour,
            ),
        )
    cands[0] = replace(cands[0], degenerate=signs)

    def why_not(c: CandidateScore) -> str:
        if not np.isfinite(c.score):
            return "could not be fitted"
        if c.name == recovered and signs:
            return "degenerate: " + "; ".join(d.message for d in signs)
        if not credible(c) and best_sound is not None:
            return (
                f"explains held-back {source} {100 * c.score:.2f} % against "
                f"{best_sound.name}'s {100 * best_sound.score:.2f} % (more than "
                f"{100 * SCORE_TOLERANCE:.0f} % worse)"
            )
        if _less_consistent(c.colour, best_colour, COLOUR_TOLERANCE):
            return (
                f"colours less consistent between frames than with {best_by_colour} "
                f"({c.colour:.4f} against {best_colour:.4f})"
            )
        return ""

    cands = [replace(c, excluded=why_not(c)) for c in cands]
    pool_ok = [c for c in cands if not c.excluded] or [cands[-1]]
    best = min(pool_ok, key=lambda c: c.score)
    srgb_ok = not cands[-1].excluded
    if (
        best.name != "srgb"
        and srgb_ok
        and np.isfinite(srgb_score)
        and not (best.score < (1.0 - SRGB_MARGIN) * srgb_score)
    ):
        best = cands[-1]
    ordered = sorted(cands, key=lambda c: (bool(c.excluded), c.score))
    others = [c for c in ordered if c.name != best.name and not c.excluded] or [
        c for c in ordered if c.name != best.name and np.isfinite(c.score)
    ]
    runner = others[0] if others else None
    margin = (
        (1.0 - best.score / runner.score)
        if runner is not None and runner.score > 0
        else float("nan")
    )
    fallback = bool(signs)

    # every candidate's curve and its residual per level, for the report and the inspector
    curves = {recovered: full.g, **{f: c.g for f, c in family_curves.items()}, "srgb": srgb.g}
    residuals = {k: level_residuals(g, all_pairs, log_r, lo, hi) for k, g in curves.items()}

    # --- the winner, fitted on the whole bracket ---------------------------------------------
    if best.name == recovered:
        from .joint import _fit_to_curve

        curve = _fit_to_curve(
            full, recovered, ratios, {**fit_kw, "source": source}, f"channel model {chosen_model}"
        )
    elif best.name == "srgb":
        curve = srgb
    else:
        curve = replace(family_curves[best.name], exposure_ratios=ratios)
    vs = f"; {runner.name} {100 * runner.score:.2f} %" if runner is not None else ""
    msg = f"auto: {best.name} explains held-back {source} to {100 * best.score:.2f} %{vs}"
    if best.name == "srgb" and not (np.isfinite(margin) and margin >= SRGB_MARGIN):
        msg += f" (sRGB kept: no curve explains them {100 * SRGB_MARGIN:.0f} % better)"
    elif np.isfinite(margin) and margin >= 0.005:
        msg += f" ({100 * margin:.0f} % better)"
    n_out = sum(1 for c in cands if c.excluded and c.name != recovered)
    if n_out:
        msg += (
            f"; {n_out} candidate(s) left out for colours less consistent between frames"
            if any("colours less consistent" in c.excluded for c in cands)
            else ""
        )
    if fallback:
        msg = (
            "auto: the recovered curve is degenerate ("
            + "; ".join(d.message for d in signs)
            + f"); fell back to {best.name} "
            f"({100 * best.score:.2f} %{vs})"
        )
    selection = ResponseSelection(
        chosen=best.name,
        candidates=tuple(ordered),
        runner_up=None if runner is None else runner.name,
        margin=margin,
        fallback=fallback,
        recovered=recovered,
        degenerate=signs,
        source=source,
        message=msg,
        parameters={
            "cutoff": cutoff,
            "low_cut": low_cut,
            "smoothing": smoothing,
            "channel_model": chosen_model,
        },
        curves=curves,
        residuals=residuals,
    )
    status = "fallback" if fallback else curve.status
    message = msg if not curve.message or curve.method == "srgb" else f"{msg}; {curve.message}"
    return replace(
        curve,
        selection=selection,
        status=status,
        message=message,
        parameters={**curve.parameters, "auto": True},
        exposure_ratios=curve.exposure_ratios or ratios,
        residuals=residuals[best.name],
    )

"""Plain-language verdicts: why a bracket merged badly, from the stages' own result objects.

Each :class:`Verdict` has a stable ``code``, a ``severity`` (``"error"``: the merge is wrong or
impossible; ``"warning"``: it is probably degraded; ``"info"``), the frames it concerns and a
sentence a photographer can act on. The rules read diagnostics that the stages already computed
(capture warnings, pair statuses, EXIF mismatches, per-channel ratios, registration costs and
the merge's clipping and ghost maps); nothing is recomputed here.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from .status import Severity

if TYPE_CHECKING:  # pragma: no cover
    from .pipeline import PipelineResult

__all__ = [
    "Verdict",
    "diagnose",
    "exif_pairs",
    "MISMATCH_STOPS",
    "CLIPPED_FRACTION",
    "GHOST_FRACTION",
    "MAX_COLOUR_ERROR",
]

#: EXIF and estimated ratios further apart than this (in stops) give a verdict.
MISMATCH_STOPS = 0.15
#: Pixels clipped in every frame above this fraction: the darkest frame is too bright.
CLIPPED_FRACTION = 0.002
#: Pixels under the noise floor in every frame above this fraction: the brightest is too dark.
UNDEREXPOSED_FRACTION = 0.02
#: A bracket whose registered pairs all moved less than this (pixels) is static (a tripod): a
#: pair that cannot be registered rightly keeps the identity.
STATIC_SHIFT_PX = 1.0
#: A pair whose motion moves the corners by at most this (pixels) is not said to have had its
#: whole-frame ratio biased by motion: so little content enters or leaves the frame (the
#: memorial's film scans move 1.04 px and their two ratio estimates differ by 18 %; the hand-held
#: Pixel 7's pairs move 6-22 px).
MOTION_BIAS_PX = 2.0
#: Pixels flagged as ghosts above this fraction: something moved.
GHOST_FRACTION = 0.01
#: Median chromaticity error of a merge against its reference frame above which its colours
#: are said to drift (non-linear input, :mod:`hdrcore.merge.colour_check`).
MAX_COLOUR_ERROR = 0.02


@dataclass(frozen=True)
class Verdict:
    code: str
    severity: Severity
    message: str
    frames: tuple[int, ...] = ()

    def to_json(self) -> dict[str, Any]:
        return {
            "code": self.code,
            "severity": self.severity,
            "message": self.message,
            "frames": list(self.frames),
        }


_CAPTURE: dict[str, tuple[Severity, str]] = {
    "iso-changed": (
        "info",
        "ISO changed between frames (a phone bracketing with exposure "
        "compensation): the recorded exposure is time x ISO, which is what orders "
        "and chains the frames; noise differs between exposures.",
    ),
    "aperture-changed": (
        "warning",
        "The aperture changed between frames: the recorded "
        "exposure includes it, but depth of field and vignetting differ, which "
        "can show as ghosts and wrong ratios.",
    ),
    "duplicate-exposure": (
        "info",
        "Two frames have the same exposure: they add no dynamic "
        "range, but both are merged (averaging lowers the noise).",
    ),
    "times-swapped": (
        "warning",
        "The exposure times contradict the pixels: a frame is brighter "
        "than one with a longer exposure. The frames were ordered by brightness and "
        "the ratios measured from the pixels.",
    ),
    "out-of-order": (
        "warning",
        "The exposure times contradict the pixels (frames darker than "
        "shorter exposures): the frames were ordered by brightness; check the "
        "times or whether a file belongs to another bracket.",
    ),
    "mixed-cameras": (
        "error",
        "The frames come from different cameras: they cannot be one bracket.",
    ),
    "capture-span": (
        "warning",
        "The frames were taken far apart in time: a bracket is shot within seconds or minutes, "
        "so some files may belong to other shots (the merge mixes them).",
    ),
    "no-exposure-times": (
        "info",
        "No exposure times in the files: the ratios come from the "
        "histograms alone (the paper's method).",
    ),
    "no-white-balance": (
        "warning",
        "A RAW file records no as-shot white balance: the colour "
        "matrix's daylight neutral (or unity) was used; colours may be off.",
    ),
    "frame-saturated": ("warning", "A frame is almost entirely saturated and contributes little."),
    "frame-black": ("warning", "A frame is almost entirely black and contributes little."),
    "colour-space-unknown": (
        "warning",
        "A frame's ICC profile names a colour space hdrcore does not convert: its colours were "
        "taken as sRGB and may be off.",
    ),
    "colour-space-differs": (
        "warning",
        "The frames are encoded in different colour spaces: the merge took them all as the one "
        "most of them use; export them alike.",
    ),
}


def _corner_shift_px(rp: Any) -> float:
    """How far a registered pair's motion moves the frame's corners at most, pixels (NaN for a
    pair that was not registered or has no size)."""
    from .geometry import corner_error

    if rp is None or not getattr(rp, "usable", False) or rp.shape is None:
        return float("nan")
    return float(corner_error(rp.homography, np.eye(3), rp.shape[:2]).max())


def _names(result: PipelineResult, frames: tuple[int, ...]) -> str:
    fr = result.bracket.frames
    return ", ".join(fr[k].name for k in frames if 0 <= k < len(fr))


def _frame_list(indices: list[int], names: list[str]) -> str:
    label = "frame" if len(indices) == 1 else "frames"
    nums = ", ".join(str(k) for k in indices[:-1])
    nums = f"{nums} and {indices[-1]}" if nums else str(indices[-1])
    return f"{label} {nums} ({', '.join(names[k] for k in indices)})"


def _unused_frames(result: PipelineResult) -> list[Verdict]:
    """Frames left out because they carry no signal (black, saturated): one verdict per kind."""
    unused = result.unused_frames
    if not unused:
        return []
    full = result.loaded_bracket
    all_names = [f.name for f in full.frames]
    used = [k for k in range(len(full)) if k not in {u.index for u in unused}]
    out = []
    for kind, meaning in (
        ("black", "below the noise floor everywhere"),
        ("saturated", "clipped everywhere"),
        (
            "unlinked",
            "no exposure ratio to the other frames could be "
            "measured and the files carry no exposure times",
        ),
    ):
        ks = [u.index for u in unused if u.status == kind]
        if not ks:
            continue
        verb = "is" if len(ks) == 1 else "are"
        out.append(
            Verdict(
                f"frame-{kind}-unused",
                "warning",
                f"{_frame_list(ks, all_names)} {verb} {kind} ({meaning}): not used; the merge uses "
                f"{_frame_list(used, all_names)}. Ratios across the gap come from the frames on "
                "either side (or their EXIF times).",
                tuple(ks),
            )
        )
    return out


def _response_and_colour(result: PipelineResult) -> list[Verdict]:
    """The response that was used (and why), a degenerate curve, the colour check, per-frame
    white balance and local tone mapping (issue 15)."""
    out: list[Verdict] = []
    resp = result.response
    sel = None if resp is None else resp.selection
    b = result.bracket
    spec = result.params.response
    calibrated = not isinstance(spec, str) or os.path.isfile(spec)  # a curve given: no trade
    if not b.is_linear and not calibrated and "no-exposure-times" in b.warning_codes():
        out.append(
            Verdict(
                "ratios-response-ambiguous",
                "warning",
                "No exposure times: the ratios of JPEG/PNG/TIFF frames come from their "
                "histograms through the response, and the two trade off (a response raised to "
                "a power explains the same frames with every ratio raised to that power): "
                "the ratios' intervals assume the response is right, and the radiance map's "
                "contrast is only as right as both. Measured on the real frobisher bracket "
                "without its EXIF: ratios 13.1 and 13.2 where the times say 8 (8.05 with them). "
                "Give the times (--times) if you know them.",
            )
        )
    if sel is not None and sel.fallback:
        out.append(
            Verdict(
                "response-fallback",
                "warning",
                sel.message + ". The merge uses "
                f"{sel.chosen}; its colours and ratios are only as right as that "
                "curve.",
            )
        )
    elif resp is not None and sel is not None:
        out.append(Verdict("response-auto", "info", sel.message + "."))
        from .response.degeneracy import degeneracy

        differ = [d for d in degeneracy(resp.g) if d.code == "channels-disagree"]
        if differ:
            out.append(
                Verdict(
                    "response-channels-differ",
                    "info",
                    f"The response's channels differ: {differ[0].message.split(': ', 1)[-1]}. "
                    "Held-back data support separate curves ("
                    + str(sel.parameters.get("channel_model", "separate"))
                    + " model); the "
                    "merge's colours are checked against the frames.",
                )
            )
    elif resp is not None and resp.method not in ("srgb", "linear"):
        from .response.degeneracy import degeneracy

        signs = degeneracy(
            resp.g,
            active=[c.active_constraints for c in resp.channels] or None,
            n_nodes=resp.max_level if resp.channels else None,
        )
        if signs:
            out.append(
                Verdict(
                    "response-degenerate",
                    "warning",
                    f"The {resp.method} response looks degenerate: "
                    + "; ".join(d.message for d in signs)
                    + ". Try --response auto (it falls back to a safe curve) or --response srgb.",
                )
            )
    check = (result.colour or {}).get("check")
    if not check:
        return out
    if check.get("before") is not None and check.get("after") is not None:
        out.extend(_colour_measured(check))  # not measured in a draft
    balance = check.get("white_balance") or {}
    if balance.get("unmeasured"):
        out.append(
            Verdict(
                "white-balance-unmeasured",
                "info",
                f"{balance['message'][0].upper()}{balance['message'][1:]}.",
                tuple(balance["unmeasured"]),
            )
        )
    ltm = check.get("local_tone_mapping") or {}
    if ltm.get("detected"):
        out.append(
            Verdict(
                "locally-tone-mapped",
                "warning",
                f"{ltm['message'][0].upper()}{ltm['message'][1:]}. No single response turns such "
                "frames into radiance: the merged map is a compromise (exposure ratios and "
                "contrast are approximate), its colours are taken from the frames; the preview is "
                "an exposure fusion of the frames (Mertens et al. 2007).",
            )
        )
    return out


def _colour_measured(check: dict) -> list[Verdict]:
    """The verdicts on a non-linear merge's measured colour (``check``: its
    ``result.colour["check"]`` with ``before`` and ``after``)."""
    out: list[Verdict] = []
    before, after = check["before"], check["after"]
    # linear-encoded frames (colour_check.frame_encoding) are compared as their response
    # decodes them, not as sRGB (which would call their own colour a drift)
    linear = (check.get("frame_encoding") or {}).get("encoding") == "linear"
    err = after.get("merge_error" if linear else "merge_error_srgb")
    own = [
        f["best_error_balanced"]
        for f in after.get("frame_colours") or []
        if f.get("best_error_balanced") is not None
    ]
    if check.get("anchor") is not None and before.get("merge_error_srgb") is not None:
        out.append(
            Verdict(
                "colour-anchored",
                "info",
                "The merge was given the frames' own colours (as a screen shows them: each pixel "
                "the colour of the frames well exposed there, the one nearest mid-grey first): "
                + (
                    f"median chromaticity error against each frame where it is the best exposed "
                    f"at most {max(own):.3f}; "
                    if own
                    else ""
                )
                + f"against the reference frame {before['merge_error_srgb']:.3f} -> {err:.3f}.",
            )
        )
    elif err is not None and err > MAX_COLOUR_ERROR:
        out.append(
            Verdict(
                "colour-drift",
                "warning",
                f"The merge's colours drift from the frames': median chromaticity error "
                f"{err:.3f} against the reference frame (over {MAX_COLOUR_ERROR}). The response's "
                "channels disagree or the frames were rendered differently.",
            )
        )
    odd = after.get("white_balance_differs") or []
    if odd:
        wb = after["white_balance"]
        out.append(
            Verdict(
                "white-balance-differs",
                "warning",
                "The white balance changes between frames: "
                + ", ".join(
                    f"frame {k} red/green x{wb[k][0]:.3f}, blue/green x{wb[k][2]:.3f}" for k in odd
                )
                + " against the reference frame. The camera re-balanced each shot (auto white "
                "balance, or a scan balanced frame by frame); "
                + (
                    "the merge divides it out (those frames' regions take the reference's balance)."
                    if (check.get("white_balance") or {}).get("applied")
                    else "the regions those frames expose best keep their colours."
                ),
                tuple(odd),
            )
        )
    return out


def exif_pairs(times_source: str) -> set[str]:
    """The pairs ("3-4") a merge took from EXIF, as :class:`~hdrcore.pipeline.Pipeline` lists
    them in ``times_source`` ("estimated; EXIF for pairs 1-2, 11-12"): whole names, so pair
    1-2 is not found inside 11-12."""
    if "EXIF for pairs" not in times_source:
        return set()
    tail = times_source.split("EXIF for pairs", 1)[1]
    return {part.strip() for part in tail.split(",") if part.strip()}


def _excluded_colour(result: PipelineResult, names: list[str]) -> list[Verdict]:
    """A warning when the excluded colour matches no pixel of some frames (or of all): their
    marks are then merged as picture. JPEG cannot keep an exact colour (its compression moved
    the memorial scans' pure blue (0, 0, 255) to about (1, 1, 245) inside the marks and by up
    to 170 levels at their thin edges: none matched in the darkest frames as JPEG)."""
    counts = result.excluded_pixels
    colour = result.params.exclude_colour
    if counts is None or colour is None or all(n > 0 for n in counts):
        return []
    b = result.bracket
    empty = [k for k, n in enumerate(counts) if n == 0]
    shown = tuple(int(c) for c in colour)
    jpeg = any(str(b.frames[k].meta.format).lower() in ("jpeg", "jpg") for k in empty)
    why = (
        " JPEG compression cannot keep an exact colour: convert the marks to a colour the "
        "frames hold (or mask them before compressing), or give lossless frames."
        if jpeg
        else ""
    )
    if len(empty) == len(counts):
        text = (
            f"The excluded colour {shown} matches no pixel of any frame: nothing was left out.{why}"
        )
    else:
        listed = ", ".join(f"{k} ({names[k]})" for k in empty)
        text = (
            f"The excluded colour {shown} matches no pixel of frame"
            f"{'' if len(empty) == 1 else 's'} {listed} while the others have "
            f"{max(counts)} at most: whatever marks those frames have are merged and "
            f"registered as picture.{why}"
        )
    return [Verdict("excluded-colour-unmatched", "warning", text, tuple(empty))]


def diagnose(result: PipelineResult) -> list[Verdict]:
    """Verdicts for one pipeline run, most severe first."""
    out: list[Verdict] = []
    b = result.bracket
    names = [f.name for f in b.frames]
    out.extend(_unused_frames(result))
    marker = result.marker_colour
    if marker is not None:
        out.append(
            Verdict(
                "marker-colour-excluded",
                "info",
                f"Pixels of the pure colour {tuple(int(c) for c in marker)} sit at the same "
                "places in "
                "the darkest and the brightest frame (a mask or border marking, not the scene): "
                "they "
                "were left out of every estimate, as --exclude-colour "
                f"{','.join(str(int(c)) for c in marker)} does.",
                (),
            )
        )

    out.extend(_excluded_colour(result, names))

    for w in b.warnings:
        if w.code in _CAPTURE:
            sev, text = _CAPTURE[w.code]
            detail = f" ({w.message})" if w.message else ""
            out.append(Verdict(w.code, sev, text + detail, tuple(w.frames)))

    ex = result.exposures
    for k, p in enumerate(ex.pairs):
        pair = (p.dark, p.bright)
        label = f"frames {p.dark} and {p.bright} ({names[p.dark]}, {names[p.bright]})"
        if p.status == "no-overlap":
            exif = ex.exif_ratios[k] if k < len(ex.exif_ratios) else None
            gap = f" ({math.log2(exif):.1f} stops apart)" if exif and exif > 0 else ""
            covered = f"{p.dark}-{p.bright}" in exif_pairs(result.times_source)
            out.append(
                Verdict(
                    "no-overlap",
                    "warning" if covered else "error",
                    f"No brightness overlap between {label}{gap}: no level is well exposed in "
                    "both, "
                    "so their exposure ratio cannot be measured"
                    + (
                        "; the EXIF ratio was used."
                        if covered
                        else ". Shoot with smaller steps or give the exposure times."
                    ),
                    pair,
                )
            )
        elif p.status == "channels-disagree" or p.channels_disagree:
            chans = ", ".join(f"{c} {r:.3f}" for c, r in zip("RGB", p.channel_ratios, strict=False))
            out.append(
                Verdict(
                    "channels-disagree",
                    "warning",
                    f"The colour channels disagree on the ratio of {label} ({chans}): a wrong "
                    "white "
                    "level, clipping in one channel or a wrong response (a colour cast in the "
                    "merge).",
                    pair,
                )
            )
        elif p.status != "ok":
            out.append(
                Verdict(
                    f"ratio-{p.status}",
                    "warning",
                    f"The exposure ratio of {label} is unreliable ({p.status}): {p.message}",
                    pair,
                )
            )
        mism = ex.mismatch_stops[k] if k < len(ex.mismatch_stops) else None
        if mism is not None and math.isfinite(mism) and abs(mism) > MISMATCH_STOPS and p.ok:
            out.append(
                Verdict(
                    "exif-mismatch",
                    "warning",
                    f"EXIF says {label} are {ex.exif_ratios[k]:.3g}x apart but the images say "
                    f"{p.ratio:.3g}x ({mism:+.2f} stops): the EXIF time is wrong or the shutter is "
                    "inaccurate; the measured ratio is used.",
                    pair,
                )
            )
    if "EXIF for pairs" in result.times_source:
        out.append(
            Verdict(
                "times-fallback",
                "warning",
                "Some exposure ratios could not be measured reliably from the images; the "
                "EXIF ratios were used for them in the merge "
                f"({result.times_source.split('; ', 1)[1]}).",
            )
        )

    reg = result.registration
    if reg is not None:
        failed = [rp for rp in reg.pairs if not rp.usable]
        moved = [math.hypot(rp.dx, rp.dy) for rp in reg.pairs if rp.usable]
        for rp in reg.pairs:
            if rp.status != "weak":
                continue
            res = rp.residual
            what = res.message if res is not None else rp.message
            out.append(
                Verdict(
                    "registration-weak",
                    "warning",
                    f"Frames {rp.dark} and {rp.bright} ({names[rp.dark]}, {names[rp.bright]}) were "
                    f"aligned with the {rp.model} model, but a check independent of it finds "
                    f"{what}. "
                    "Edges there may be doubled in the merge"
                    + (
                        "; the homography model (perspective) may fit better."
                        if rp.model != "homography"
                        else "; deghosting may help."
                    ),
                    (rp.dark, rp.bright),
                )
            )
        static = bool(moved) and max(moved) <= STATIC_SHIFT_PX
        for rp in failed:
            label = f"frames {rp.dark} and {rp.bright} ({names[rp.dark]}, {names[rp.bright]})"
            if static:
                out.append(
                    Verdict(
                        "registration-identity",
                        "info",
                        f"{label} could not be registered ({rp.status}: {rp.message}); they keep "
                        "the "
                        f"identity. The other pairs moved by at most {max(moved):.2f} px, so the "
                        "bracket looks static (tripod) and the identity is right.",
                        (rp.dark, rp.bright),
                    )
                )
            else:
                out.append(
                    Verdict(
                        "registration-failed",
                        "warning",
                        f"Registration failed for {label} ({rp.status}): {rp.message}. They were "
                        "merged without alignment (identity) and may be blurred or ghosted; "
                        + (
                            f"the other pairs moved by up to {max(moved):.1f} px."
                            if moved
                            else "no pair could be registered."
                        ),
                        (rp.dark, rp.bright),
                    )
                )

    out.extend(_response_and_colour(result))
    m = result.merge
    hist = result.exposures_histogram
    if hist is not None and hist is not ex:
        reg_pairs = result.registration.pairs if result.registration is not None else ()
        for k, (a, c) in enumerate(zip(hist.ratios, ex.ratios, strict=False)):
            if math.isfinite(a) and math.isfinite(c) and c > 0 and abs(a / c - 1) > 0.01:
                shift = _corner_shift_px(reg_pairs[k]) if k < len(reg_pairs) else float("nan")
                if math.isfinite(shift) and shift <= MOTION_BIAS_PX:
                    # the frames did not move: not motion (the memorial's film scans, a
                    # tripod: -18 % between two estimators that weigh the levels differently)
                    out.append(
                        Verdict(
                            "ratio-estimates-differ",
                            "info",
                            f"The whole-frame ratio of frames {k} and {k + 1} differs by "
                            f"{100 * (a / c - 1):+.1f} % from the one measured on the "
                            f"registered pixels ({ex.method}: {c:.4g}), which the merge uses. "
                            f"The frames moved by at most {shift:.2f} px, so not because of "
                            "motion: the two estimates weigh the levels differently (noise, "
                            "clipping or a response that does not fit everywhere).",
                            (k, k + 1),
                        )
                    )
                    continue
                how_far = f" ({shift:.1f} px at the corners)" if math.isfinite(shift) else ""
                out.append(
                    Verdict(
                        "motion-biased-ratio",
                        "info",
                        f"Hand-held motion{how_far} biased the whole-frame ratio of frames {k} and "
                        f"{k + 1} by {100 * (a / c - 1):+.1f} %; it was measured again after "
                        f"registration ({ex.method}: {c:.4g}).",
                        (k, k + 1),
                    )
                )
    if m is None:
        order = {"error": 0, "warning": 1, "info": 2}
        out.sort(key=lambda v: order.get(v.severity, 3))
        return out
    summary_clipped = m.clipped_fraction
    if summary_clipped > CLIPPED_FRACTION:
        out.append(
            Verdict(
                "darkest-clipped",
                "warning",
                f"{100 * summary_clipped:.2f} % of the pixels are saturated even in the darkest "
                f"frame ({names[0]}): highlights there are clipped in the HDR. Add a shorter "
                "exposure.",
                (0,),
            )
        )
    under = m.underexposed_fraction
    if under > UNDEREXPOSED_FRACTION:
        out.append(
            Verdict(
                "brightest-underexposed",
                "info",
                f"{100 * under:.1f} % of the pixels are under the noise floor even in the "
                "brightest "
                f"frame ({names[-1]}): shadows there are noisy. Add a longer exposure.",
                (len(names) - 1,),
            )
        )
    ghost = m.ghost_fraction
    if ghost > GHOST_FRACTION:
        out.append(
            Verdict(
                "ghosts",
                "warning",
                f"{100 * ghost:.1f} % of the pixels disagree between aligned frames beyond their "
                "noise: something moved (or the alignment is off). See the ghost layer.",
            )
        )
    if not any(v.severity in ("error", "warning") for v in out):
        out.append(
            Verdict(
                "ok",
                "info",
                "The bracket merged cleanly: ratios measured, frames "
                "aligned, no clipping or ghosts beyond the thresholds.",
            )
        )
    order = {"error": 0, "warning": 1, "info": 2}
    out.sort(key=lambda v: order.get(v.severity, 3))
    return out

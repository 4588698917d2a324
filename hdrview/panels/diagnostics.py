"""Diagnostics panel: one row per consecutive pair for the whole bracket (estimated and EXIF ratio,
mismatch in stops, inliers, standard error, registration cost, statuses), the pipeline's
plain-language verdicts and the capture warnings of the loader."""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Any

import viser

from hdrcore.io import Bracket
from hdrcore.status import SEVERITIES, Severity

from ._draw import fmt, md_table
from .frames import warnings_markdown

if TYPE_CHECKING:  # the library's stages are imported on first use, not with the page
    from hdrcore.exposure import BracketExposureResult, ExposureRatioResult
    from hdrcore.pipeline import PipelineResult
    from hdrcore.registration import BracketRegistration

__all__ = [
    "DiagnosticsPanel",
    "bundle_files",
    "frames_table",
    "pairs_table",
    "summary_line",
    "times_words",
    "verdicts_markdown",
]


def pairs_table(
    exposure: BracketExposureResult,
    registration: BracketRegistration | None,
    bracket: Bracket | None = None,
    histogram: BracketExposureResult | None = None,
) -> str:
    """One row per pair. ``histogram``: the whole-frame estimate when the merge's ratios were
    measured again on the registered pixels: the inlier column then gives both counts, the
    BTF and Masks tabs' (histograms) and the merge's (registered pixels)."""
    again = histogram is not None and histogram is not exposure
    before = histogram.pairs if again and histogram is not None else ()
    header = [
        "pair",
        "ratio",
        "95 % interval",
        "EXIF ratio",
        "mismatch (stops)",
        "inlier equations" + (" (histograms → registered pixels)" if again else ""),
        "ratio status",
        "cost before → after",
        "dx, dy, angle",
        "registration status",
    ]
    rows = []
    names = None if bracket is None else [f.name for f in bracket.frames]
    for k, p in enumerate(exposure.pairs):
        exif = exposure.exif_ratios[k] if k < len(exposure.exif_ratios) else None
        mism = exposure.mismatch_stops[k] if k < len(exposure.mismatch_stops) else None
        r = (
            registration.pairs[k]
            if registration is not None and k < len(registration.pairs)
            else None
        )
        cost = "—" if r is None else f"{fmt(r.cost_before, 3)} → {fmt(r.cost_after, 3)}"
        motion = "—" if r is None else (f"{fmt(r.dx, 3)}, {fmt(r.dy, 3)}, {fmt(r.angle_deg, 3)}°")
        rows.append(
            [
                f"{p.dark}→{p.bright}"
                + ("" if names is None else f" ({names[p.dark]}, {names[p.bright]})"),
                fmt(p.ratio, 6),
                _interval_text(p),
                fmt(exif, 6),
                fmt(mism, 3),
                (f"{before[k].n_inliers}/{before[k].n_equations} → " if k < len(before) else "")
                + f"{p.n_inliers}/{p.n_equations}",
                p.status,
                cost,
                motion,
                "off" if r is None else r.status,
            ]
        )
    rel = ", ".join(fmt(v, 6) for v in exposure.relative_exposures)
    return (
        md_table(header, rows) + f"\n\nRelative exposures (darkest = 1): {rel}; exposure stage "
        f"**{exposure.status}**: {fmt(exposure.message)}"
    )


def frames_table(result: PipelineResult) -> str:
    """Per frame as loaded: used or not (and why), its measured noise; the noise floor used."""
    loaded = result.loaded_bracket
    signals = {s.index: s for s in result.frame_signals}
    noise = result.noise
    header = ["frame", "file", "used", "signal", "noise σ (levels)", "noise measured from"]
    rows = []
    for k, f in enumerate(loaded.frames):
        sig = signals.get(k)
        fn = noise.frames[k] if noise is not None and k < len(noise.frames) else None
        rows.append(
            [
                str(k),
                f.name,
                "yes" if sig is None or sig.usable else f"**no: {sig.status}**",
                "—" if sig is None else fmt(sig.reason),
                "—" if fn is None else fmt(fn.sigma, 3),
                "—" if fn is None else fn.source,
            ]
        )
    text = md_table(header, rows)
    if noise is not None:
        floor = result.noise_floor
        text += (
            f"\n\nNoise floor used: **{fmt(floor, 4)}** levels (default: "
            f"{fmt(noise.k_sigma, 2)} × σ = {fmt(noise.k_sigma * noise.sigma, 4)}, at least "
            f"{fmt(noise.minimum, 4)}; σ = {fmt(noise.sigma, 3)} from {noise.source})."
        )
    return text


def _interval_text(p: ExposureRatioResult) -> str:
    """The pair's calibrated 95 % interval, ``low–high (±h %)``, or a dash."""
    (lo, hi), h = p.interval, p.ci95_relative
    if not all(map(math.isfinite, (lo, hi, h))):
        return "—"
    return f"{lo:.4g}–{hi:.4g} (±{100 * h:.2g} %)"


_SEVERITY: dict[Severity, tuple[str, str, str]] = {  # title, what it means, one of them
    "error": ("Problems", "the result is wrong or missing here", "problem"),
    "warning": ("Warnings", "the result may be off; check", "warning"),
    "info": ("Notes", "for information", "note"),
}


def times_words(result: PipelineResult) -> str:
    """Where the merge's exposure times came from, as the summary and the status line say it:
    the pipeline's ``times_source``, except that "estimated; EXIF for pairs 0-1, ..., 4-5"
    (every pair fell back) reads as EXIF for every pair (the Pixel 7 said "estimated")."""
    from hdrcore.diagnose import exif_pairs

    source = result.times_source or ""
    n_pairs = len(result.bracket) - 1
    used = exif_pairs(source)
    if source.startswith("estimated") and n_pairs > 0 and len(used) >= n_pairs:
        source = "EXIF for every pair (none could be measured reliably from the images)"
    elif len(used) == 1:
        source = source.replace("EXIF for pairs ", "EXIF for pair ")
    # the recorded times are EXIF's unless a times file gave them (the memorial's scans)
    kinds = {f.meta.exposure_time_source for f in result.bracket.frames}
    if "times-file" in kinds:
        word = "the times file" if kinds == {"times-file"} else "the recorded times"
        source = source.replace("EXIF", word)
    return source


def summary_line(result: PipelineResult) -> str:
    """One sentence: what was merged and how many problems, warnings and notes there are."""
    counts = {sev: sum(1 for v in result.verdicts if v.severity == sev) for sev in SEVERITIES}
    n_all, n_used = len(result.loaded_bracket), len(result.bracket)
    head = (
        f"**Merged {n_used} of {n_all} frames**" if result.merge is not None else "**Not merged**"
    )
    source = times_words(result)
    if source:
        head += f" (exposure times: {fmt(source)})"
    parts = []
    for sev in SEVERITIES:
        n = counts[sev]
        if n:
            word = _SEVERITY[sev][2]
            parts.append(f"{n} {word}{'s' if n != 1 else ''}")
    return head + ("; " + ", ".join(parts) if parts else "; no problems found") + "."


#: Verdicts about pairs that a long bracket repeats pair after pair: from ``GROUP_AT`` of one
#: code on they are one line, the pairs named, each pair's own words folded under it (the
#: memorial's nine "exposure ratio unreliable" warnings were nine screen lines each).
GROUP_TITLES = {
    "ratio-uncertain": "The exposure ratio is unreliable (uncertain)",
    "ratio-unstable": "The exposure ratio is unreliable (unstable)",
    "channels-disagree": "The colour channels disagree on the exposure ratio",
    "registration-weak": "Residual motion is left after alignment",
    "registration-identity": "The pair could not be registered and keeps the identity",
    "motion-biased-ratio": "Hand-held motion biased the whole-frame ratio (measured again)",
    "ratio-estimates-differ": "The whole-frame and registered-pixel ratios differ",
    "exif-mismatch": "EXIF and the images disagree on the exposure ratio",
    "no-overlap": "No brightness overlap: the exposure ratio cannot be measured",
    "registration-failed": "Registration failed: merged without alignment",
}
GROUP_AT = 3


def _group_title(code: str) -> str | None:
    """The folded line's words for a pair verdict's code (``ratio-<status>`` for any status the
    ratio estimators give), ``None`` for verdicts that are not grouped."""
    if code in GROUP_TITLES:
        return GROUP_TITLES[code]
    if code.startswith("ratio-") and code != "ratio-estimates-differ":
        return f"The exposure ratio is unreliable ({code[len('ratio-') :]})"
    return None


def _verdict_line(v: Any) -> str:
    msg = fmt(v.message)
    return f"- <span title='{v.code}'>{msg}</span>" if v.code else f"- {msg}"


def _grouped_line(code: str, group: list[Any]) -> str:
    """One line for ``group`` (verdicts of one code about pairs), each pair's message in a
    fold (HTML ``details``: the page renders markdown's HTML)."""
    pairs = ", ".join("-".join(str(f) for f in v.frames) for v in group)
    items = "".join(f"<li>{fmt(v.message)}</li>" for v in group)  # (fmt escapes)
    return (
        f"- <details><summary><span title='{code}'>{_group_title(code)}</span> for "
        f"{len(group)} pairs ({pairs})</summary><ul>{items}</ul></details>"
    )


def verdicts_markdown(result: PipelineResult) -> str:
    """The summary line, then the verdicts grouped by severity, worst first (codes on hover);
    a code repeated for :data:`GROUP_AT` or more pairs is one folded line."""
    verdicts = result.verdicts
    lines = [summary_line(result)]
    if not verdicts:
        return lines[0]
    for sev in SEVERITIES:
        title, what, _ = _SEVERITY[sev]
        group = [v for v in verdicts if v.severity == sev]
        if not group:
            continue
        lines.append(f"\n**{title}** ({what})\n")
        by_code: dict[str, list[Any]] = {}
        for v in group:
            by_code.setdefault(v.code, []).append(v)
        done: set[str] = set()
        for v in group:
            same = by_code[v.code]
            if _group_title(v.code) and len(same) >= GROUP_AT and all(x.frames for x in same):
                if v.code not in done:
                    lines.append(_grouped_line(v.code, same))
                    done.add(v.code)
                continue
            lines.append(_verdict_line(v))
    return "\n".join(lines)


class DiagnosticsPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.verdicts = gui.add_markdown("No bracket loaded.")
        self.table = gui.add_markdown("")
        self.frames = gui.add_markdown("")
        self.warnings = gui.add_markdown("")

    def show(
        self, bracket: Bracket | None, result: PipelineResult | None, view: dict[str, Any]
    ) -> None:
        if bracket is None:
            self.verdicts.content = "No bracket loaded."
            self.table.content = ""
            self.frames.content = ""
            self.warnings.content = ""
            return
        self.warnings.content = warnings_markdown(bracket)
        if result is None:
            self.verdicts.content = "_Waiting for the pipeline's verdicts (hdrcore.pipeline)._"
            self.table.content = ""
            return
        self.verdicts.content = verdicts_markdown(result)
        self.table.content = pairs_table(
            result.exposures, result.registration, result.bracket, result.exposures_histogram
        )
        self.frames.content = frames_table(result)


def bundle_files(bracket: Any, result: Any, *panels: Any) -> list[tuple[str, bytes]]:
    """The panels' current plots and images for the diagnostics bundle."""
    files: list[tuple[str, bytes]] = []
    for p in panels:
        files.extend(p.bundle_files())
    return files

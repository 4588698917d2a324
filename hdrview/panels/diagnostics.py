"""Diagnostics panel: one row per consecutive pair for the whole bracket (estimated and EXIF ratio,
mismatch in stops, inliers, standard error, registration cost, statuses), the pipeline's
plain-language verdicts and the capture warnings of the loader."""

from __future__ import annotations

import math
from typing import Any

import viser

from ._access import exposure_of, registration_of, verdicts_of
from ._draw import fmt, md_table
from .frames import warnings_markdown

__all__ = ["DiagnosticsPanel", "bundle_files", "frames_table", "pairs_table",
           "summary_line", "verdicts_markdown"]


def pairs_table(exposure: Any, registration: Any, bracket: Any = None) -> str:
    header = ["pair", "ratio", "95 % interval", "EXIF ratio", "mismatch (stops)",
              "inlier equations",
              "ratio status", "cost before → after", "dx, dy, angle", "registration status"]
    rows = []
    names = None if bracket is None else [f.name for f in bracket.frames]
    for k, p in enumerate(exposure.pairs):
        exif = exposure.exif_ratios[k] if k < len(exposure.exif_ratios) else None
        mism = exposure.mismatch_stops[k] if k < len(exposure.mismatch_stops) else None
        r = registration.pairs[k] if registration is not None and k < len(registration.pairs) \
            else None
        cost = "—" if r is None else f"{fmt(r.cost_before, 3)} → {fmt(r.cost_after, 3)}"
        motion = "—" if r is None else (
            f"{fmt(r.dx, 3)}, {fmt(r.dy, 3)}, {fmt(r.angle_deg, 3)}°")
        rows.append([
            f"{p.dark}→{p.bright}" + ("" if names is None else
                                      f" ({names[p.dark]}, {names[p.bright]})"),
            fmt(p.ratio, 6), _interval_text(p), fmt(exif, 6),
            fmt(mism, 3), f"{p.n_inliers}/{p.n_equations}", p.status, cost, motion,
            "off" if r is None else r.status,
        ])
    rel = ", ".join(fmt(v, 6) for v in exposure.relative_exposures)
    return (md_table(header, rows)
            + f"\n\nRelative exposures (darkest = 1): {rel}; exposure stage "
            f"**{exposure.status}**: {fmt(exposure.message)}")


def frames_table(result: Any) -> str:
    """Per frame as loaded: used or not (and why), its measured noise; the noise floor used."""
    loaded = getattr(result, "loaded_bracket", None)
    signals = {s.index: s for s in getattr(result, "frame_signals", ())}
    noise = getattr(result, "noise", None)
    if loaded is None:
        return ""
    header = ["frame", "file", "used", "signal", "noise σ (levels)", "noise measured from"]
    rows = []
    for k, f in enumerate(loaded.frames):
        sig = signals.get(k)
        fn = noise.frames[k] if noise is not None and k < len(noise.frames) else None
        rows.append([
            str(k), f.name, "yes" if sig is None or sig.usable else f"**no: {sig.status}**",
            "—" if sig is None else fmt(sig.reason),
            "—" if fn is None else fmt(fn.sigma, 3),
            "—" if fn is None else fn.source,
        ])
    text = md_table(header, rows)
    if noise is not None:
        floor = getattr(result, "noise_floor", None)
        text += (f"\n\nNoise floor used: **{fmt(floor, 4)}** levels (default: "
                 f"{fmt(noise.k_sigma, 2)} × σ = {fmt(noise.k_sigma * noise.sigma, 4)}, at least "
                 f"{fmt(noise.minimum, 4)}; σ = {fmt(noise.sigma, 3)} from {noise.source}).")
    return text


def _interval_text(p: Any) -> str:
    """The pair's calibrated 95 % interval, ``low–high (±h %)``, or a dash."""
    (lo, hi), h = p.interval, p.ci95_relative
    if not all(map(math.isfinite, (lo, hi, h))):
        return "—"
    return f"{lo:.4g}–{hi:.4g} (±{100 * h:.2g} %)"


_SEVERITY = (("error", "Problems", "the result is wrong or missing here"),
             ("warning", "Warnings", "the result may be off; check"),
             ("info", "Notes", "for information"))


def summary_line(result: Any) -> str:
    """One sentence: what was merged and how many problems, warnings and notes there are."""
    verdicts = [v for v in verdicts_of(result) if not isinstance(v, str)]
    counts = {sev: sum(1 for v in verdicts if getattr(v, "severity", "info") == sev)
              for sev, _, _ in _SEVERITY}
    loaded = getattr(result, "loaded_bracket", None) or getattr(result, "bracket", None)
    used = getattr(result, "bracket", None)
    merged = getattr(result, "merge", None)
    n_all = len(loaded) if loaded is not None else 0
    n_used = len(used) if used is not None else n_all
    head = (f"**Merged {n_used} of {n_all} frames**" if merged is not None
            else "**Not merged**")
    source = getattr(result, "times_source", None)
    if source:
        head += f" (exposure times: {fmt(source)})"
    parts = []
    for sev, _title, _ in _SEVERITY:
        n = counts[sev]
        if n:
            word = {"error": "problem", "warning": "warning", "info": "note"}[sev]
            parts.append(f"{n} {word}{'s' if n != 1 else ''}")
    return head + ("; " + ", ".join(parts) if parts else "; no problems found") + "."


def verdicts_markdown(result: Any) -> str:
    """The summary line, then the verdicts grouped by severity, worst first (codes on hover)."""
    verdicts = verdicts_of(result)
    lines = [summary_line(result)]
    if not verdicts:
        return lines[0]
    for sev, title, what in _SEVERITY:
        group = [v for v in verdicts if (getattr(v, "severity", "info") if not isinstance(
            v, str) else "info") == sev]
        if not group:
            continue
        lines.append(f"\n**{title}** ({what})\n")
        for v in group:
            code = getattr(v, "code", None)
            msg = fmt(getattr(v, "message", None) or str(v))
            lines.append(f"- <span title='{code}'>{msg}</span>" if code else f"- {msg}")
    return "\n".join(lines)


class DiagnosticsPanel:
    def __init__(self, gui: viser.GuiApi) -> None:
        self._gui = gui
        self.verdicts = gui.add_markdown("No bracket loaded.")
        self.table = gui.add_markdown("")
        self.frames = gui.add_markdown("")
        self.warnings = gui.add_markdown("")

    def show(self, bracket: Any, result: Any, view: dict) -> None:
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
        exposure = exposure_of(result)
        self.table.content = ("" if exposure is None else
                              pairs_table(exposure, registration_of(result),
                                          getattr(result, "bracket", None)))
        self.frames.content = frames_table(result)


def bundle_files(bracket: Any, result: Any, *panels: Any) -> list[tuple[str, bytes]]:
    """The panels' current plots and images for the diagnostics bundle."""
    files: list[tuple[str, bytes]] = []
    for p in panels:
        files.extend(p.bundle_files())
    return files

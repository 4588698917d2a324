"""``hdrcore response FILE... --method NAME``: recover the camera response of a bracket.

Prints ``{"method", "channels": [{"levels", "g"}], "exposure_ratios", ...}`` with ``--json``
(``g`` at every input level, normalised to ``g(0) = 0``, ``g(max level) = 1``); ``--plot`` draws
the curves into a PNG and ``--save`` writes the curve as JSON for ``--response FILE`` of the
other commands. Outputs are written atomically and never replace a file without ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from typing import Any

import numpy as np

from .._threads import set_workers
from ..errors import ParameterError
from ..io import check_output_path
from ..response import DEFAULT_METHOD, RESPONSE_METHODS, recover_response
from ._common import (
    add_bracket_arguments,
    check_outputs_first,
    input_files,
    load_bracket_from_args,
    print_json,
    print_warnings,
)
from ._params import add_param_arguments

__all__ = ["RESPONSE_FIELDS", "add_parser", "exclusion_mask", "run"]

#: the pipeline's parameters ``hdrcore response`` offers. It does not run the pipeline: its
#: ``--method``, ``--cutoff``, ``--order`` and ``--no-monotone`` have no pipeline field, it
#: fits RAW frames too (the pipeline takes them as linear) and it needs exposure times (the
#: pipeline estimates them from the histograms): see tests/cli/test_response_ratios_routes.py
RESPONSE_FIELDS = ("exclude_colour", "workers")


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "response",
        help="recover the camera response curve of a bracket (Cerman & Hlavac 2006, sec. 4)",
        description="Recover the inverse camera response g (level -> linear exposure) per "
        "channel. Histogram methods need no registration (hand-held brackets).",
    )
    add_bracket_arguments(p)
    p.add_argument(
        "--method",
        default=DEFAULT_METHOD,
        metavar="NAME",
        help=f"one of {', '.join(RESPONSE_METHODS)} (default {DEFAULT_METHOD})",
    )
    p.add_argument(
        "--cutoff",
        type=float,
        default=0.98,
        help="only levels below cutoff*max enter the fit (seed's fix; 1.0 = naive)",
    )
    p.add_argument(
        "--order",
        default=None,
        help="polynomial order for mitsunaga1999/grossberg2003 (integer or 'auto')",
    )
    p.add_argument(
        "--no-monotone",
        action="store_true",
        help="do not constrain the fit to a non-decreasing curve (for comparison only)",
    )
    # the pipeline's flags for what it shares with the other commands (same parsing)
    add_param_arguments(p, RESPONSE_FIELDS)
    p.add_argument("--plot", metavar="PNG", help="draw the curves into this PNG")
    p.add_argument("--save", metavar="JSON", help="save the curve for --response of other commands")
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def exclusion_mask(frames: list[np.ndarray], colour: tuple[int, int, int]) -> np.ndarray:
    """True where no frame has exactly ``colour``: the pixels the fit uses (the pipeline's
    exclusion, :func:`hdrcore.pipeline.colour_masks`)."""
    from ..pipeline import colour_masks

    return ~np.logical_or.reduce(colour_masks(frames, colour))


def run(args: argparse.Namespace) -> int:
    outputs = [p for p in (args.plot, args.save) if p]
    if len(set(outputs)) != len(outputs):
        raise ParameterError("--plot and --save must name different files")
    check_outputs_first(outputs, args)
    bracket = load_bracket_from_args(args)
    for out in outputs:
        check_output_path(out, force=args.force, inputs=input_files(args, bracket.paths))
    frames = [f.levels for f in bracket.frames]
    recorded = bracket.exposure_times
    times = (
        None if any(t is None for t in recorded) else [float(t) for t in recorded if t is not None]
    )
    params: dict[str, Any] = {"max_level": bracket.max_level, "cutoff": args.cutoff}
    if args.no_monotone:
        params["monotone"] = False
    if args.order is not None:
        params["order"] = args.order if args.order == "auto" else _int(args.order, "--order")
    if args.exclude_colour is not None:
        params["mask"] = exclusion_mask(frames, args.exclude_colour)
    with set_workers(args.workers):
        curve = recover_response(frames, times, method=args.method, **params)
    if args.plot:
        curve.plot(args.plot, force=args.force, inputs=input_files(args, bracket.paths))
    if args.save:
        curve.save(args.save, force=args.force, inputs=input_files(args, bracket.paths))
    d = curve.to_json()
    out = {
        "method": curve.method,
        "max_level": curve.max_level,
        "channels": [
            {"name": c["name"], "levels": c["levels"], "g": c["g"], "fit": c["fit"]}
            for c in d["channels"]
        ],
        "exposure_ratios": d["exposure_ratios"],
        "status": curve.status,
        "message": curve.message,
        "parameters": d["parameters"],
        "files": list(bracket.paths),
        "warnings": [w.to_json() for w in bracket.warnings],
        "outputs": {"plot": args.plot, "curve": args.save},
    }
    if args.json:
        print_json(out)
    else:
        print(f"method {curve.method}: {curve.status} {curve.message}".rstrip())
        print("exposure ratios: " + ", ".join(f"{r:.4g}" for r in curve.exposure_ratios))
        quart = [round(q * curve.max_level) for q in (0.25, 0.5, 0.75)]
        for c, fit in enumerate(curve.channels):
            g = ", ".join(f"g({z})={curve.g[c, z]:.4f}" for z in quart)
            order = f" order {fit.order}" if fit.order is not None else ""
            print(f"  {curve.channel_names[c]}:{order} residual {fit.residual_rms:.3g}  {g}")
        print_warnings(bracket)
    if bracket.is_linear:
        print(
            "hdrcore: warning: the frames are linear (RAW); the response should be the identity",
            file=sys.stderr,
        )
    return 0


def _int(text: str, what: str) -> int:
    try:
        return int(text)
    except ValueError:
        raise ParameterError(f"{what} must be an integer or 'auto'", found=repr(text)) from None

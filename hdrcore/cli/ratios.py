"""``hdrcore ratios FILE...``: exposure ratios from histograms (Cerman & Hlavac 2006, section 5)."""

from __future__ import annotations

import argparse

import numpy as np

from ..errors import ParameterError
from ._common import (
    add_bracket_arguments,
    load_bracket_from_args,
    print_json,
    print_unused_frames,
    print_warnings,
)
from ._params import add_param_arguments, params_from_args

__all__ = ["RATIOS_FIELDS", "add_parser", "colour_mask", "run"]

#: the pipeline's parameters ``hdrcore ratios`` offers
RATIOS_FIELDS = (
    "saturation",
    "noise_floor",
    "response",
    "exposure_method",
    "noise_sigma",
    "exclude_colour",
    "workers",
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ratios", help="estimate exposure ratios of consecutive frames from their histograms"
    )
    add_bracket_arguments(p)
    add_param_arguments(p, RATIOS_FIELDS, command="ratios")
    p.add_argument(
        "--registered",
        action="store_true",
        help="hand-held brackets: register the frames (as 'hdrcore align') and measure the "
        "ratios again from the registered pixels (without it: histograms only, the "
        "paper's method, no registration)",
    )
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def colour_mask(levels: list[np.ndarray], colour: tuple[int, ...]) -> np.ndarray:
    """True where no frame has exactly ``colour``: the pixels to use."""
    first = np.asarray(levels[0])
    if first.ndim != 3 or first.shape[2] != len(colour):
        raise ParameterError(
            "--exclude-colour needs colour frames with one level per channel",
            expected=f"{len(colour)} channels",
            found=str(first.shape),
        )
    from ..pipeline import colour_masks

    return ~np.logical_or.reduce(colour_masks([np.asarray(f) for f in levels], colour))


def run(args: argparse.Namespace) -> int:
    from ..pipeline import Pipeline, ratios_json

    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    # The same response, defaults and exclusions as 'hdrcore merge' and 'hdrcore align'.
    # --noise-sigma is the pipeline's noise_sigma: the whole-frame estimate's noise matching.
    params = params_from_args(args, RATIOS_FIELDS, registration_previews=False)
    if args.registered and args.noise_sigma is not None:
        raise ParameterError("--noise-sigma applies to the histogram estimate, not --registered")
    pres = Pipeline(bracket, params).run(until="overlap_ratios" if args.registered else "ratios")
    print_unused_frames(pres)
    res = pres.exposures
    bracket = pres.bracket  # the frames used: a black or saturated frame is left out
    # the colour left out: the one asked for, or a marking the pipeline found by itself
    colour = pres.params.exclude_colour
    levels = [f.levels for f in bracket.frames]
    mask = None if colour is None else colour_mask(levels, colour)
    out = {
        "masked_fraction": None if mask is None else float(1.0 - mask.mean()),
        "marker_colour": None if pres.marker_colour is None else list(pres.marker_colour),
        "method": res.method,
        **ratios_json(bracket, res),
        "frames_not_used": [u.to_json() for u in pres.unused_frames],
        "noise": None if pres.noise is None else pres.noise.to_json(),
        "noise_floor_used": pres.noise_floor,
        "saturation_used": pres.saturation,
    }
    for d, p in zip(out["pairs"], res.pairs, strict=True):
        d["region_std_error"] = p.to_json()["region_std_error"]
    if args.json:
        print_json(out)
    else:
        for d in out["pairs"]:
            print(
                f"{d['dark']}-{d['bright']}: ratio {d['ratio']:.4f} "
                f"(exif {d['exif_ratio']}) {d['status']}: {d['message']}"
            )
    return 0 if res.status == "ok" else 1

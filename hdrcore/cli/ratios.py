"""``hdrcore ratios FILE...``: exposure ratios from histograms (Cerman & Hlavac 2006, section 5)."""

from __future__ import annotations

import argparse

import numpy as np

from ..errors import ParameterError
from ..exposure import DEFAULT_METHOD, EXPOSURE_METHODS, bracket_exposures
from ._common import (
    add_bracket_arguments,
    add_exclude_colour_argument,
    add_level_arguments,
    load_bracket_from_args,
    print_json,
    print_unused_frames,
    print_warnings,
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ratios", help="estimate exposure ratios of consecutive frames from their histograms"
    )
    add_bracket_arguments(p)
    add_level_arguments(p)
    p.add_argument("--method", default=DEFAULT_METHOD, choices=list(EXPOSURE_METHODS),
                   help="estimator (default: %(default)s)")
    p.add_argument("--noise-sigma", type=float, default=None, metavar="S",
                   help="additive noise in levels for noise matching (refined method)")
    add_exclude_colour_argument(p, "--mask-colour")
    p.add_argument(
        "--registered", action="store_true",
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
        raise ParameterError("--mask-colour needs colour frames with one level per channel",
                             expected=f"{len(colour)} channels", found=str(first.shape))
    from ..pipeline import colour_masks

    return ~np.logical_or.reduce(colour_masks([np.asarray(f) for f in levels], colour))


def run(args: argparse.Namespace) -> int:
    from ..pipeline import Pipeline, PipelineParams, ratios_json

    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    max_level = bracket.frames[0].max_level
    # The same response, defaults and exclusions as 'hdrcore merge' and 'hdrcore align'.
    params = PipelineParams(
        saturation=args.saturation, noise_floor=args.noise_floor, response=args.response,
        exposure_method=args.method,
        exclude_colour=args.exclude_colour, registration_previews=False,
    )
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
    if args.noise_sigma is not None:
        times = [None if f.meta.exposure_time is None else float(f.meta.exposure_time)
                 for f in bracket.frames]
        res = bracket_exposures(
            levels, max_level, method=args.method, exposure_times=times, mask=mask,
            saturation=pres.saturation, noise_floor=pres.noise_floor, lut=pres.lut,
            noise_sigma=args.noise_sigma,
        )
    out = {"masked_fraction": None if mask is None else float(1.0 - mask.mean()),
           "marker_colour": None if pres.marker_colour is None else list(pres.marker_colour),
           "method": res.method, **ratios_json(bracket, res),
           "frames_not_used": [u.to_json() for u in pres.unused_frames],
           "noise": None if pres.noise is None else pres.noise.to_json(),
           "noise_floor_used": pres.noise_floor, "saturation_used": pres.saturation}
    for d, p in zip(out["pairs"], res.pairs, strict=True):
        d["region_std_error"] = p.to_json()["region_std_error"]
    if args.json:
        print_json(out)
    else:
        for d in out["pairs"]:
            print(f"{d['dark']}-{d['bright']}: ratio {d['ratio']:.4f} "
                  f"(exif {d['exif_ratio']}) {d['status']}: {d['message']}")
    return 0 if res.status == "ok" else 1

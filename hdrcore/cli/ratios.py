"""``hdrcore ratios FILE...``: exposure ratios from histograms (Cerman & Hlavac 2006, section 5)."""

from __future__ import annotations

import argparse

import numpy as np

from ..errors import ParameterError
from ..exposure import DEFAULT_METHOD, EXPOSURE_METHODS, bracket_exposures
from ._common import add_bracket_arguments, load_bracket_from_args, print_json, print_warnings


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "ratios", help="estimate exposure ratios of consecutive frames from their histograms"
    )
    add_bracket_arguments(p)
    p.add_argument("--saturation", type=float, metavar="Z",
                   help="saturation level Z in levels (default 97%% of the largest level)")
    p.add_argument("--noise-floor", type=float, metavar="N",
                   help="ignore levels at or below N (default 2%% of the largest level, >= 3)")
    p.add_argument("--response", default="auto", metavar="NAME|FILE",
                   help="linearisation: 'auto' (linear for RAW, recovered from the histograms "
                        "for JPEG/PNG/TIFF), 'linear', 'srgb', a method (debevec1997, "
                        "debevec-histogram, mitsunaga1999, grossberg2003) or a saved curve")
    p.add_argument("--method", default=DEFAULT_METHOD, choices=list(EXPOSURE_METHODS),
                   help="estimator (default: %(default)s)")
    p.add_argument("--noise-sigma", type=float, default=None, metavar="S",
                   help="additive noise in levels for noise matching (refined method)")
    p.add_argument("--mask-colour", "--exclude-colour", dest="mask_colour", metavar="R,G,B",
                   type=_colour,
                   help="exclude pixels of exactly this colour in any frame (in levels), e.g. "
                        "0,0,255 for the blue border of memorial-debevec")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def _colour(text: str) -> tuple[int, ...]:
    try:
        values = tuple(int(v) for v in text.split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected three integer levels R,G,B (e.g. 0,0,255), found {text!r}") from None
    if len(values) != 3 or min(values) < 0:
        raise argparse.ArgumentTypeError(
            f"expected three non-negative integer levels R,G,B, found {text!r}")
    return values


def colour_mask(levels: list[np.ndarray], colour: tuple[int, ...]) -> np.ndarray:
    """True where no frame has exactly ``colour``: the pixels to use."""
    first = np.asarray(levels[0])
    if first.ndim != 3 or first.shape[2] != len(colour):
        raise ParameterError("--mask-colour needs colour frames with one level per channel",
                             expected=f"{len(colour)} channels", found=str(first.shape))
    hit = np.zeros(first.shape[:2], bool)
    target = np.asarray(colour)
    for f in levels:
        hit |= np.all(np.asarray(f) == target, axis=-1)
    return ~hit


def run(args: argparse.Namespace) -> int:
    from ..pipeline import Pipeline, PipelineParams

    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    frames = bracket.frames
    max_level = frames[0].max_level
    times = [None if f.meta.exposure_time is None else float(f.meta.exposure_time) for f in frames]
    levels = [f.levels for f in frames]
    mask = None if args.mask_colour is None else colour_mask(levels, args.mask_colour)
    # The same response, defaults and exclusions as 'hdrcore merge' and 'hdrcore align'.
    params = PipelineParams(
        saturation=args.saturation, noise_floor=args.noise_floor, response=args.response,
        exposure_method=args.method,
        exclude_colour=None if args.mask_colour is None else tuple(args.mask_colour),
    )
    pres = Pipeline(bracket, params).run(until="ratios")
    res = pres.exposures
    if args.noise_sigma is not None:
        res = bracket_exposures(
            levels, max_level, method=args.method, exposure_times=times, mask=mask,
            saturation=pres.saturation, noise_floor=pres.noise_floor, lut=pres.lut,
            noise_sigma=args.noise_sigma,
        )
    out = {
        "masked_fraction": None if mask is None else float(1.0 - mask.mean()),
        "frames": [
            {"path": f.meta.path,
             "exif_exposure_time": times[k],
             "relative_exposure": res.relative_exposures[k]}
            for k, f in enumerate(frames)
        ],
        "pairs": [
            {"dark": p.dark, "bright": p.bright, "ratio": p.ratio,
             "initial_ratio": p.initial_ratio, "iterations": p.iterations,
             "equations": p.n_equations, "inliers": p.n_inliers,
             "exif_ratio": res.exif_ratios[k], "mismatch_stops": res.mismatch_stops[k],
             "std_error": p.std_error,
             "region_std_error": p.to_json()["region_std_error"],
             "status": p.status, "message": p.message}
            for k, p in enumerate(res.pairs)
        ],
    }
    if args.json:
        print_json(out)
    else:
        for d in out["pairs"]:
            print(f"{d['dark']}-{d['bright']}: ratio {d['ratio']:.4f} "
                  f"(exif {d['exif_ratio']}) {d['status']}: {d['message']}")
    return 0 if res.status == "ok" else 1

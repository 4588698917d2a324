"""``hdrcore align FILE...``: hand-held registration (Cerman & Hlavac 2006, section 6).

Registers consecutive frames on the linearised green channel, the darker one multiplied by the
exposure ratio (estimated from the histograms by :mod:`hdrcore.exposure`; EXIF as a fallback),
and chains the pair transforms to the reference frame.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from ..errors import BracketError
from ..exposure import bracket_exposures, default_noise_floor, default_saturation, srgb_lut
from ..registration import MODELS, REGISTRATION_METHODS, register_bracket
from ._common import add_bracket_arguments, load_bracket_from_args, print_json, print_warnings


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "align", help="register hand-held frames: sub-pixel shift and rotation per pair"
    )
    add_bracket_arguments(p)
    p.add_argument("--model", default="euclidean", choices=list(MODELS),
                   help="motion model (default: %(default)s)")
    p.add_argument("--method", default="fast", choices=list(REGISTRATION_METHODS),
                   help="search (default: %(default)s; 'Cerman 2006' is the seed's simplex)")
    p.add_argument("--threshold", type=float, default=0.1, metavar="T",
                   help="eq. 7 normalisation threshold t as a fraction of the saturation level "
                        "(default: %(default)s)")
    p.add_argument("--reference", type=int, default=None, metavar="N",
                   help="index of the reference frame, darkest = 0 (default: the middle one)")
    p.add_argument("--ratios", default="histogram", choices=("histogram", "exif"),
                   help="exposure ratios from the histograms (hdrcore.exposure, falls back to "
                        "EXIF) or from EXIF times (default: %(default)s)")
    p.add_argument("--response", metavar="FILE|srgb|linear",
                   help="linearisation of non-linear frames: a response JSON from "
                        "'hdrcore response', 'srgb' (default for JPEG/PNG) or 'linear'")
    p.add_argument("--saturation", type=float, metavar="Z",
                   help="saturation level in levels (default 97%% of the largest level)")
    p.add_argument("--noise-floor", type=float, metavar="N",
                   help="noise floor in levels (default 2%% of the largest level, >= 3)")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def _lut(args: argparse.Namespace, linear: bool, max_level: int) -> np.ndarray:
    choice = args.response
    if choice is None:
        choice = "linear" if linear else "srgb"
    if choice.lower() == "linear":
        return np.arange(max_level + 1, dtype=np.float64) / max_level
    if choice.lower() == "srgb":
        return srgb_lut(max_level)
    from ..response.curve import ResponseCurve

    return ResponseCurve.load(choice).to_lut(max_level)


def _exif_ratios(bracket) -> list[float]:
    ratios = [bracket.exif_ratio(k, k + 1) for k in range(len(bracket) - 1)]
    if any(r is None or not math.isfinite(r) or r <= 0 for r in ratios):
        raise BracketError(
            "exposure ratios unavailable: no usable EXIF exposure times",
            expected="EXIF ExposureTime in every frame, or --times FILE", found=str(ratios),
        )
    return [float(r) for r in ratios]


def run(args: argparse.Namespace) -> int:
    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    frames = bracket.frames
    max_level = frames[0].max_level
    lut = _lut(args, all(f.is_linear for f in frames), max_level)
    g = lut[1] if lut.ndim == 2 else lut  # green channel
    sat_level = default_saturation(max_level) if args.saturation is None else args.saturation
    nf_level = default_noise_floor(max_level) if args.noise_floor is None else args.noise_floor
    saturation = float(g[min(max_level, int(math.floor(sat_level)))])
    noise_floor = float(g[min(max_level, int(math.ceil(nf_level)))])

    source = args.ratios
    if source == "histogram":
        times = [None if f.meta.exposure_time is None else float(f.meta.exposure_time)
                 for f in frames]
        est = bracket_exposures(
            [f.levels for f in frames], max_level, exposure_times=times, lut=lut,
            saturation=args.saturation, noise_floor=args.noise_floor,
        )
        rel = est.relative_exposures
        ratios = [rel[k + 1] / rel[k] for k in range(len(rel) - 1)]
        if est.status != "ok" or not all(math.isfinite(r) and r > 0 for r in ratios):
            print(f"hdrcore: warning: histogram ratios unusable ({est.message}); using EXIF",
                  file=sys.stderr)
            ratios, source = _exif_ratios(bracket), "exif"
    else:
        ratios = _exif_ratios(bracket)

    linear = [g[f.levels[..., 1]].astype(np.float32) for f in frames]
    res = register_bracket(
        linear, ratios, reference=args.reference, method=args.method, model=args.model,
        threshold=args.threshold, saturation=saturation, noise_floor=noise_floor,
        previews=False,
    )
    keys = ("dark", "bright", "matrix", "dx", "dy", "angle_deg", "cost_before", "cost_after",
            "status", "message", "ratio", "overlap", "iterations", "seconds")
    out = {
        "reference": res.reference,
        "model": res.model,
        "method": res.method,
        "ratios_source": source,
        "pairs": [{k: p.to_json()[k] for k in keys} for p in res.pairs],
        "to_reference": [np.asarray(m).tolist() for m in res.to_reference],
    }
    if args.json:
        print_json(out)
    else:
        for p in res.pairs:
            print(f"{p.dark}-{p.bright}: dx {p.dx:+.3f} dy {p.dy:+.3f} angle {p.angle_deg:+.4f} "
                  f"deg  cost {p.cost_before:.5f} -> {p.cost_after:.5f}  {p.status}: "
                  f"{p.message}")
    return 0 if res.ok else 1

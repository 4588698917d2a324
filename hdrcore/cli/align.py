"""``hdrcore align FILE...``: hand-held registration (Cerman & Hlavac 2006, section 6).

Runs the pipeline up to the registration: the exposure ratios from the histograms (section 5;
``--ratios exif`` uses the metadata instead), the response for non-linear frames, then each
consecutive pair registered on the linearised green channel with the darker frame multiplied by
the ratio, and the pair transforms chained to the reference frame. Same defaults as
``hdrcore merge``, so ``align`` shows exactly the motion the merge will use.
"""

from __future__ import annotations

import argparse

from ..pipeline import LOCAL_CHOICES, Pipeline, PipelineParams
from ..registration import MODELS, REGISTRATION_METHODS
from ._common import (
    add_bracket_arguments,
    add_exclude_colour_argument,
    add_level_arguments,
    load_bracket_from_args,
    print_json,
    print_unused_frames,
    print_warnings,
)

__all__ = ["add_parser", "run"]


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "align", help="register hand-held frames: sub-pixel shift and rotation per pair",
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_bracket_arguments(p)
    add_exclude_colour_argument(p)
    add_level_arguments(p)
    p.add_argument("--model", default="similarity", choices=list(MODELS),
                   help="motion model (default: %(default)s)")
    p.add_argument("--local", default="auto", choices=LOCAL_CHOICES,
                   help="local refinement after the model (a displacement field per frame; "
                        "default: %(default)s, the frames left misaligned)")
    p.add_argument("--method", default="fast", choices=list(REGISTRATION_METHODS),
                   help="search (default: %(default)s; 'Cerman 2006' is the seed's simplex)")
    p.add_argument("--threshold", type=float, default=0.1, metavar="T",
                   help="eq. 7 normalisation threshold t as a fraction of the saturation level "
                        "(default: %(default)s)")
    p.add_argument("--reference", type=int, default=None, metavar="N",
                   help="index of the reference frame, darkest = 0 (default: the middle one)")
    p.add_argument("--ratios", default="histogram", choices=("histogram", "exif"),
                   help="exposure ratios from the histograms (falls back to EXIF when they "
                        "cannot be measured) or from EXIF times (default: %(default)s)")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    params = PipelineParams(
        saturation=args.saturation, noise_floor=args.noise_floor, threshold=args.threshold,
        align=args.model, local=args.local, reference=args.reference, response=args.response,
        times="exif" if args.ratios == "exif" else "estimated",
        registration_method=args.method, exclude_colour=args.exclude_colour,
        registration_previews=False,
    )
    result = Pipeline(bracket, params).run(until="registration")
    print_unused_frames(result)
    reg = result.registration
    assert reg is not None  # align is never "none" here
    out = result.registration_json()
    out["frames"] = [f.path for f in result.bracket.frames]
    out["frames_not_used"] = [u.to_json() for u in result.unused_frames]
    if args.json:
        print_json(out)
    else:
        for p in reg.pairs:
            print(f"{p.dark}-{p.bright}: dx {p.dx:+.3f} dy {p.dy:+.3f} angle {p.angle_deg:+.4f} "
                  f"deg  cost {p.cost_before:.5f} -> {p.cost_after:.5f}  {p.status}: "
                  f"{p.message}")
    return 0 if reg.ok else 1

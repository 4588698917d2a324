"""``hdrcore align FILE...``: hand-held registration (Cerman & Hlavac 2006, section 6).

Runs the pipeline up to the registration: the exposure ratios from the histograms (section 5;
``--times-source exif`` uses the metadata instead), the response for non-linear frames, then each
consecutive pair registered on the linearised green channel with the darker frame multiplied by
the ratio, and the pair transforms chained to the reference frame. Same flags and defaults as
``hdrcore merge`` (``--align auto``: the similarity, and the homography for the pairs with
perspective left), so ``align`` shows exactly the motion the merge will use.
"""

from __future__ import annotations

import argparse

from ..pipeline import ALIGN_CHOICES, Pipeline
from ._common import (
    add_bracket_arguments,
    load_bracket_from_args,
    print_json,
    print_unused_frames,
    print_warnings,
)
from ._params import add_param_arguments, params_from_args

__all__ = ["ALIGN_FIELDS", "add_parser", "run"]

#: the pipeline's parameters ``hdrcore align`` offers: those the stages up to the registration
#: read, with the same defaults as ``hdrcore merge``
ALIGN_FIELDS = (
    "saturation",
    "noise_floor",
    "threshold",
    "align",
    "local",
    "reference",
    "response",
    "times",
    "exposure_method",
    "noise_sigma",
    "registration_method",
    "registration_max_pixels",
    "exclude_colour",
    "workers",
)


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "align",
        help="register hand-held frames: sub-pixel shift and rotation per pair",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_bracket_arguments(p)
    add_param_arguments(
        p,
        ALIGN_FIELDS,
        command="align",
        choices={"align": [c for c in ALIGN_CHOICES if c != "none"]},
    )
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    bracket = load_bracket_from_args(args)
    print_warnings(bracket)
    params = params_from_args(args, ALIGN_FIELDS, registration_previews=False)
    result = Pipeline(bracket, params).run(until="registration")
    print_unused_frames(result)
    reg = result.registration
    out = result.registration_json()
    assert reg is not None and out is not None  # align is never "none" here
    out["frames"] = [f.path for f in result.bracket.frames]
    out["frames_not_used"] = [u.to_json() for u in result.unused_frames]
    if args.json:
        print_json(out)
    else:
        for p in reg.pairs:
            print(
                f"{p.dark}-{p.bright}: dx {p.dx:+.3f} dy {p.dy:+.3f} angle {p.angle_deg:+.4f} "
                f"deg  cost {p.cost_before:.5f} -> {p.cost_after:.5f}  {p.status}: "
                f"{p.message}"
            )
    return 0 if reg.ok else 1

"""``hdrcore info FILE...``: what the loader sees (order, metadata, capture warnings)."""

from __future__ import annotations

import argparse

from ._common import add_bracket_arguments, load_bracket_from_args, print_json, print_warnings


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "info", help="load a bracket and report its frames, metadata and capture warnings"
    )
    add_bracket_arguments(p)
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    bracket = load_bracket_from_args(args)
    frames = []
    for k, f in enumerate(bracket.frames):
        d = f.meta.to_json()
        d["index"] = k
        d["width"], d["height"] = f.shape[1], f.shape[0]
        frames.append(d)
    out = {
        "order_source": bracket.order_source,
        "frames": frames,
        "exif_ratios": [bracket.exif_ratio(k, k + 1) for k in range(len(bracket) - 1)],
        "warnings": [w.to_json() for w in bracket.warnings],
    }
    if args.json:
        print_json(out)
    else:
        for d in frames:
            t = d["exposure_time_exact"] or "unknown"
            print(
                f"{d['index']}: {d['path']}  {d['width']}x{d['height']}  {d['bit_depth']}-bit "
                f"{d['format']}  t={t} s  f/{d['f_number']}  ISO {d['iso']}"
            )
        print_warnings(bracket)
    return 0

"""Shared pieces of the subcommands: bracket arguments, JSON printing, warnings to stderr."""

from __future__ import annotations

import argparse
import json
import math
import os
import sys
from pathlib import Path
from typing import Any

import numpy as np

from .._threads import resolve_workers
from ..errors import FrameTooLargeError, HdrError, OutputError, ParameterError
from ..io import MAX_FRAME_PIXELS, Bracket, check_output_path, expand_paths, load_bracket
from ..io.atomic import same_file
from ._chatter import holding_file_warnings

__all__ = [
    "add_bracket_arguments",
    "check_outputs_first",
    "parse_colour",
    "parse_pixel_count",
    "parse_workers",
    "input_files",
    "load_bracket_from_args",
    "print_unused_frames",
    "print_json",
    "print_warnings",
    "to_jsonable",
]


def parse_pixel_count(text: str) -> int:
    """``"2e8"`` or ``"200000000"`` -> ``200000000``; 0 means no limit (an argparse ``type``)."""
    try:
        value = float(str(text).replace("_", ""))
    except ValueError:
        value = float("nan")
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(
            f"expected a number of pixels such as 2e8 (0 for no limit), found {text!r}"
        )
    return int(round(value))


def parse_workers(text: str) -> int:
    """``--workers N``: scipy's convention (``-1`` every core); an argparse ``type``."""
    try:
        value = int(text)
        resolve_workers(value)  # 0 and counts below -cores are refused here
    except (ValueError, ParameterError):
        raise argparse.ArgumentTypeError(
            f"expected a number of threads (1, 2, ...; -1 for every core, -2 all but one), "
            f"found {text!r}"
        ) from None
    return value


def suggest_pixel_limit(pixels: int) -> str:
    """A round limit just above ``pixels``, as typed: ``200000000`` -> ``"2e8"``, ``163e6`` ->
    ``"1.7e8"``."""
    exponent = max(int(math.floor(math.log10(max(pixels, 1)))), 1)
    mantissa = math.ceil(pixels / 10 ** (exponent - 1) - 1e-9) / 10
    if mantissa >= 10:
        mantissa, exponent = mantissa / 10, exponent + 1
    return f"{mantissa:g}e{exponent}"


def add_bracket_arguments(parser: argparse.ArgumentParser) -> None:
    """``FILE...`` (files or directories), ``--times FILE`` and ``--max-pixels N``."""
    parser.add_argument(
        "files",
        nargs="+",
        metavar="FILE",
        help="frames of one bracket (JPEG, PNG, TIFF, RAW) or a directory holding them",
    )
    parser.add_argument(
        "--times",
        metavar="FILE",
        help="exposure times as 'name seconds' lines (replace EXIF)",
    )
    parser.add_argument(
        "--max-pixels",
        dest="max_pixels",
        type=parse_pixel_count,
        metavar="N",
        help=f"largest frame to decode, in pixels, read from each file's header first "
        f"(default {MAX_FRAME_PIXELS / 1e6:g} MP; 2e8 is 200 MP; 0: no limit)",
    )


def parse_colour(text: str) -> tuple[int, int, int]:
    """``"0,0,255"`` -> ``(0, 0, 255)``; an argparse ``type``, so bad input is a usage error."""
    try:
        parts = tuple(int(v) for v in str(text).split(","))
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected three integer levels R,G,B (e.g. 0,0,255), found {text!r}"
        ) from None
    if len(parts) != 3 or min(parts) < 0:
        raise argparse.ArgumentTypeError(
            f"expected three non-negative integer levels R,G,B, found {text!r}"
        )
    return parts


def input_files(args: argparse.Namespace, frames: Any = ()) -> list[Path]:
    """Every file the command reads: the frames (as named, or ``frames`` once loaded), the
    ``--times`` list and a ``--response`` curve file. No output may replace any of them, even
    with ``--force``."""
    named: list[Path] = [Path(f) for f in frames]
    if not named:
        try:
            named = expand_paths(args.files)
        except HdrError:
            named = []
    for attr in ("times", "response"):
        value = getattr(args, attr, None)
        if isinstance(value, str) and value and Path(value).is_file():
            named.append(Path(value))
    return named


def check_outputs_first(outputs: list[str], args: argparse.Namespace) -> None:
    """Before any frame is decoded (seconds at 24 MP), refuse: two outputs that are one file,
    an output over any input (frames, ``--times``, ``--response``; even with ``--force``), an
    existing output without ``--force``, a missing or unwritable output folder. Unreadable
    inputs are the loader's to report."""
    paths = [Path(o) for o in outputs]
    for i, a in enumerate(paths):
        for b in paths[i + 1 :]:
            if same_file(a, b):
                raise OutputError(
                    "the same file is given for two outputs", found=f"{outputs[i]} and {b}"
                )
    inputs = input_files(args)
    for out in outputs:
        path = check_output_path(out, force=getattr(args, "force", False), inputs=inputs)
        parent = path.parent if str(path.parent) else Path(".")
        if not os.access(parent, os.W_OK | os.X_OK):
            raise OutputError(
                "cannot write in the output folder",
                path=parent,
                expected="a folder you may write in",
            )


def load_bracket_from_args(args: argparse.Namespace, **kwargs: Any) -> Bracket:
    """The bracket the arguments name; what the decoders say about its files is printed once
    it has loaded (with an error, only the error is)."""
    kwargs.setdefault("max_pixels", getattr(args, "max_pixels", None))
    try:
        with holding_file_warnings():
            return load_bracket(args.files, exposure_times=getattr(args, "times", None), **kwargs)
    except FrameTooLargeError as exc:
        raise FrameTooLargeError(
            exc.path or "",
            width=exc.width,
            height=exc.height,
            limit=exc.limit,
            hint=f"--max-pixels {suggest_pixel_limit(exc.width * exc.height)} raises it",
        ) from None


def to_jsonable(obj: Any) -> Any:
    """Convert numpy scalars/arrays, tuples and fractions into JSON-ready values."""
    if isinstance(obj, dict):
        return {str(k): to_jsonable(v) for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [to_jsonable(v) for v in obj]
    if isinstance(obj, np.ndarray):
        return to_jsonable(obj.tolist())
    if isinstance(obj, np.generic):
        return to_jsonable(obj.item())
    if isinstance(obj, float):
        return obj if np.isfinite(obj) else None
    if obj is None or isinstance(obj, (str, int, bool)):
        return obj
    return str(obj)


def print_json(obj: Any) -> None:
    sys.stdout.write(json.dumps(to_jsonable(obj), indent=2) + "\n")
    sys.stdout.flush()


def print_warnings(bracket: Bracket) -> None:
    for w in bracket.warnings:
        print(f"hdrcore: warning: {w.message}", file=sys.stderr)


def print_unused_frames(result: Any) -> None:
    """One warning line per frame the pipeline left out (black or saturated)."""
    for u in getattr(result, "unused_frames", ()):
        name = u.path.replace("\\", "/").rsplit("/", 1)[-1]
        print(f"hdrcore: warning: {name} is not used: it is {u.reason}", file=sys.stderr)

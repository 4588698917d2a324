"""One command-line flag per :class:`~hdrcore.pipeline.PipelineParams` field, built from it.

Every command that runs the pipeline adds its options with :func:`add_param_arguments` and
builds its parameters with :func:`params_from_args`, so a field has one flag (``FLAGS``), one
destination (``DESTS``: the field's name but for ``times``) and one default (the field's own)
on every command. A field the command line does not offer is listed in
``NOT_ON_COMMAND_LINE`` with the reason; ``tests/cli/test_params_flags.py`` fails for a field
in neither, and for a parser (``hdrview``'s too) that spells a field otherwise.

Old names stay for one release as hidden aliases (``DEPRECATED``): they still work and say on
stderr which flag replaces them.
"""

from __future__ import annotations

import argparse
import dataclasses
import math
import sys
from collections.abc import Callable, Iterable
from typing import Any

from ..exposure import EXPOSURE_METHODS
from ..pipeline import ALIGN_CHOICES, LOCAL_CHOICES, REFINE_CHOICES, PipelineParams
from ..registration import REGISTRATION_METHODS
from ..tonemap import TONEMAP_OPERATORS
from ._common import parse_colour, parse_pixel_count, parse_workers

__all__ = [
    "DEFAULTS",
    "DEPRECATED",
    "DESTS",
    "FLAGS",
    "NOT_ON_COMMAND_LINE",
    "add_param_arguments",
    "params_from_args",
]

#: every field's default, read from the dataclass (the command line never states its own)
DEFAULTS: dict[str, Any] = {f.name: f.default for f in dataclasses.fields(PipelineParams)}

#: the one flag of each field the command line offers: the field's name with dashes, except
#: ``times`` (``--times FILE`` is the exposure-times list every command reads)
FLAGS: dict[str, str] = {
    "saturation": "--saturation",
    "noise_floor": "--noise-floor",
    "threshold": "--threshold",
    "align": "--align",
    "local": "--local",
    "reference": "--reference",
    "response": "--response",
    "times": "--times-source",
    "exposure_method": "--exposure-method",
    "registration_method": "--registration-method",
    "tonemap": "--tonemap",
    "tonemap_exposure": "--tonemap-exposure",
    "preview_max_side": "--preview-max-side",
    "exclude_colour": "--exclude-colour",
    "ratio_fallback_stops": "--ratio-fallback-stops",
    "registration_max_pixels": "--registration-max-pixels",
    "refine_ratios": "--refine-ratios",
    "deghost": "--deghost",
    "colour_anchor": "--colour-anchor",
    "white_balance": "--white-balance",
    "noise_sigma": "--noise-sigma",
    "workers": "--workers",
}

#: where ``argparse`` keeps each field: its name, except ``times`` (``args.times`` is the file)
DESTS: dict[str, str] = {field: "times_source" if field == "times" else field for field in FLAGS}

#: fields no command line sets, and why
NOT_ON_COMMAND_LINE: dict[str, str] = {
    "working_space": "library only for now: the command line writes sRGB radiance maps",
    "registration_previews": "the inspector's overlays; the command line always switches "
    "them off (the overlays are drawn for every pair, which only the inspector shows)",
    "hold_registration": "the inspector's interim picture: a previous run's registration "
    "inputs in the same process (a command runs once; it has no previous run to hold)",
}

#: old flag -> (field, value translation) for each command that had it; kept for one release
DEPRECATED: dict[str, dict[str, tuple[str, dict[str, str]]]] = {
    "merge": {"--exposure": ("tonemap_exposure", {}), "--preview-size": ("preview_max_side", {})},
    "align": {
        "--model": ("align", {}),
        "--method": ("registration_method", {}),
        "--ratios": ("times", {"histogram": "estimated", "exif": "exif"}),
    },
    "ratios": {"--method": ("exposure_method", {}), "--mask-colour": ("exclude_colour", {})},
}


def _levels(text: str) -> float:
    """A noise level in levels: a finite number, 0 or more (an argparse ``type``)."""
    try:
        value = float(text)
    except ValueError:
        value = math.nan
    if not (math.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"expected levels, 0 or more (e.g. 1.5), found {text!r}")
    return value


def _limit(text: str) -> int | None:
    value = parse_pixel_count(text)
    return value or None


def _spec(field: str, *, choices: Iterable[str] | None = None) -> dict[str, Any]:
    """``add_argument`` keywords of a field: type, choices, metavar and help."""
    specs: dict[str, dict[str, Any]] = {
        "saturation": dict(
            type=float,
            metavar="Z",
            help="saturation level Z in levels (default 97%% of the largest level)",
        ),
        "noise_floor": dict(
            type=float,
            metavar="N",
            help="noise floor in levels (default: 3 x the read noise measured "
            "from the frames (RAW: optical-black pixels or the darkest "
            "flat regions), at least 2 levels; 8-bit JPEG/PNG/TIFF: at least "
            "2%% of the largest level; raised above a black pedestal of the "
            "darkest frame)",
        ),
        "threshold": dict(
            type=float,
            metavar="t",
            help="normalisation threshold t of eq. 7, fraction of Z (default %(default)s)",
        ),
        "align": dict(
            choices=ALIGN_CHOICES,
            help="motion model for hand-held frames (default: auto, the similarity "
            "(shift, rotation, scale), and the homography for the pairs where "
            "perspective is left; none: a tripod bracket)",
        ),
        "local": dict(
            choices=LOCAL_CHOICES,
            help="local refinement after the motion model: a smooth displacement "
            "field per frame for parallax (auto: the frames whose pair is left "
            "misaligned, kept where it lowers the measured residual; default "
            "auto)",
        ),
        "reference": dict(
            type=int,
            metavar="N",
            help="frame the others are aligned to, darkest = 0 (default: the middle one)",
        ),
        "response": dict(
            metavar="NAME|FILE",
            help="'auto' (linear for RAW, recovered from the histograms "
            "otherwise), 'linear', 'srgb', a method (debevec1997, "
            "debevec-histogram, mitsunaga1999, grossberg2003) or a saved "
            "curve .json (default auto)",
        ),
        "times": dict(
            choices=("estimated", "exif"),
            help="exposure times: estimated from the histograms (default; EXIF "
            "where they cannot be measured) or the EXIF/--times values "
            "(formerly --ratios histogram|exif of align)",
        ),
        "exposure_method": dict(
            choices=tuple(EXPOSURE_METHODS), help="exposure ratio estimator (default: %(default)s)"
        ),
        "registration_method": dict(
            choices=tuple(REGISTRATION_METHODS),
            help="registration search (default: %(default)s; 'Cerman 2006' is the seed's simplex)",
        ),
        "tonemap": dict(
            choices=tuple(sorted(TONEMAP_OPERATORS)),
            help="preview operator (default: auto, the local durand for scenes "
            "of more than 8 stops, else reinhard)",
        ),
        "tonemap_exposure": dict(
            type=float,
            metavar="EV",
            help="preview exposure in stops (default %(default)s, auto key; formerly --exposure)",
        ),
        "preview_max_side": dict(
            type=int,
            metavar="PX",
            help="longest side of the preview PNG (default %(default)s; "
            "0 = full resolution; formerly --preview-size)",
        ),
        "exclude_colour": dict(
            type=parse_colour,
            metavar="R,G,B",
            help="pixels of exactly this colour carry no data (e.g. "
            "0,0,255: the blue border marks of the Debevec-Malik "
            "memorial scans)",
        ),
        "ratio_fallback_stops": dict(
            type=float,
            metavar="STOPS",
            help="a pair whose ratio is not ok and differs from the "
            "EXIF ratio by more than this uses the EXIF ratio "
            "(default %(default)s: every such pair)",
        ),
        "registration_max_pixels": dict(
            type=_limit,
            metavar="N",
            help="register frames larger than this on their green "
            "channel binned 2x2 (4x4, ...) until they fit "
            "(default: always full resolution; 0 the same)",
        ),
        "refine_ratios": dict(
            choices=REFINE_CHOICES,
            help="after registration, measure the ratios again over each "
            "pair's common field from the registered pixels, the "
            "histograms of that field, or not (default %(default)s)",
        ),
        "deghost": dict(
            action=argparse.BooleanOptionalAction,
            help="fill each region where the frames disagree (moving objects) "
            "from one frame instead of the weighted average",
        ),
        "colour_anchor": dict(
            action=argparse.BooleanOptionalAction,
            help="non-linear input: give the merge the colour of the frames "
            "that expose each region best",
        ),
        "white_balance": dict(
            action=argparse.BooleanOptionalAction,
            help="non-linear input: divide out a frame's white balance where "
            "it differs from the reference's by more than 3 %% (measured and "
            "reported either way)",
        ),
        "noise_sigma": dict(
            type=_levels,
            metavar="S",
            help="additive noise in levels for the noise matching of the "
            "default ratio estimator (default: measured from the frames)",
        ),
        "workers": dict(
            type=parse_workers,
            metavar="N",
            help="threads for the compiled kernels, scipy's convention: -1 every "
            "core, -2 all but one (default: up to 2)",
        ),
    }
    spec = dict(specs[field])
    if choices is not None:
        spec["choices"] = tuple(choices)
    return spec


class _Deprecated(argparse.Action):
    """An old flag: sets the field like the new one and says so on stderr."""

    def __init__(
        self,
        option_strings: list[str],
        dest: str,
        *,
        new: str,
        translate: dict[str, str],
        **kwargs: Any,
    ) -> None:
        self.new, self.translate = new, translate
        super().__init__(option_strings, dest, **kwargs)

    def __call__(
        self,
        parser: argparse.ArgumentParser,
        namespace: argparse.Namespace,
        values: Any,
        option_string: str | None = None,
    ) -> None:
        program = parser.prog.split()[0]
        print(
            f"{program}: warning: {option_string} is deprecated and goes in the next "
            f"release: use {self.new}",
            file=sys.stderr,
        )
        setattr(
            namespace,
            self.dest,
            self.translate.get(values, values) if isinstance(values, str) else values,
        )


def add_param_arguments(
    parser: argparse.ArgumentParser | Any,
    fields: Iterable[str],
    *,
    command: str = "",
    choices: dict[str, Iterable[str]] | None = None,
) -> None:
    """Add the flags of ``fields`` (their defaults are the fields'), and the command's
    deprecated aliases of them (hidden from ``--help``). ``choices`` narrows a field's."""
    fields = list(fields)
    for field in fields:
        spec = _spec(field, choices=(choices or {}).get(field))
        parser.add_argument(FLAGS[field], dest=DESTS[field], default=DEFAULTS[field], **spec)
    for old, (field, translate) in DEPRECATED.get(command, {}).items():
        if field not in fields:
            continue
        spec = _spec(field, choices=(choices or {}).get(field))
        spec.pop("help", None)
        if spec.get("action") is not None:  # pragma: no cover - no boolean alias exists
            raise ValueError(f"no alias for the switch {FLAGS[field]}")
        if translate and "choices" in spec:
            spec["choices"] = tuple(translate)
        parser.add_argument(
            old,
            dest=DESTS[field],
            default=argparse.SUPPRESS,
            help=argparse.SUPPRESS,
            action=_Deprecated,
            new=FLAGS[field],
            translate=translate,
            **spec,
        )


#: the command line's spelling of a library value (``0`` = no limit -> ``None``)
_FROM_COMMAND_LINE: dict[str, Callable[[Any], Any]] = {
    "preview_max_side": lambda v: None if v is not None and v <= 0 else v,
}


def params_from_args(
    args: argparse.Namespace, fields: Iterable[str], **fixed: Any
) -> PipelineParams:
    """``PipelineParams`` of the flags of ``fields`` (as parsed) and ``fixed`` values."""
    values: dict[str, Any] = {}
    for field in fields:
        value = getattr(args, DESTS[field])
        values[field] = _FROM_COMMAND_LINE.get(field, lambda v: v)(value)
    values.update(fixed)
    return PipelineParams(**values)

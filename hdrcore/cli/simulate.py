"""``hdrcore simulate OUTDIR``: write a bracket with known ground truth (truth.json).

Frames follow the seed's simulation protocol (Cerman & Hlavac 2006, sections 4.2 and 5.3):
``M = q(f(s(E * dt)) + n)`` from a procedural radiance map, with optional hand-held motion. Exposure
times come from ``--times`` (seconds, fractions allowed, in the order given) or from ``--stops N
--frames K`` (``K`` frames ``N`` stops apart, starting at ``--base-time``, darkest first).
"""

from __future__ import annotations

import argparse
from fractions import Fraction

from ..errors import ParameterError
from ..io.times import EXPOSURE_TIME_RANGE, check_seconds
from ..synthetic import FORMATS, RESPONSES, SCENES, simulate_bracket, write_bracket
from ..synthetic.dng import CFA_PATTERNS
from ._common import print_json

__all__ = ["add_parser", "run", "parse_size", "parse_times", "bracket_times"]


def parse_size(text: str) -> tuple[int, int]:
    """``"256x384"`` -> ``(256, 384)`` (height x width)."""
    parts = str(text).lower().replace("*", "x").split("x")
    try:
        h, w = (int(p) for p in parts)
    except ValueError as exc:
        raise ParameterError(
            "bad --size", expected="HxW such as 256x384", found=repr(text)
        ) from exc
    if h < 16 or w < 16 or h > 8192 or w > 8192:
        raise ParameterError("--size out of range", expected="16..8192 per side", found=text)
    return h, w


def parse_times(text: str) -> tuple[Fraction, ...]:
    """``"1/500,1/125,1/30"`` -> exact fractions (decimals allowed); all must be > 0."""
    out = []
    for item in str(text).split(","):
        item = item.strip()
        if not item:
            continue
        try:
            t = Fraction(item)
        except (ValueError, ZeroDivisionError) as exc:
            raise ParameterError(
                "bad exposure time in --times",
                expected="seconds such as 0.01 or 1/100",
                found=repr(item),
            ) from exc
        if t <= 0:
            raise ParameterError("exposure times must be positive", found=item)
        try:
            check_seconds(t)
        except ValueError as exc:
            raise ParameterError(
                f"bad exposure time in --times, {exc}",
                expected=EXPOSURE_TIME_RANGE,
                found=repr(item),
            ) from None
        out.append(t)
    if not out:
        raise ParameterError("--times lists no exposure times", found=repr(text))
    return tuple(out)


def bracket_times(stops: float, frames: int, base: Fraction) -> tuple[Fraction, ...]:
    """``frames`` times ``stops`` apart from ``base``: exact when ``stops`` is a whole number."""
    if frames < 1 or frames > 64:
        raise ParameterError("--frames out of range", expected="1..64", found=str(frames))
    if not stops > 0:
        raise ParameterError("--stops must be positive", found=str(stops))
    if float(stops).is_integer():
        return tuple(base * (2 ** (int(stops) * k)) for k in range(frames))
    return tuple(
        Fraction(float(base) * 2.0 ** (stops * k)).limit_denominator(1_000_000)
        for k in range(frames)
    )


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="write a simulated bracket with known exposure times, response and motion",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("outdir", metavar="OUTDIR", help="directory for the frames and truth.json")
    p.add_argument("--scene", default="window", choices=sorted(SCENES), help="radiance map")
    p.add_argument("--size", default="256x384", metavar="HxW", help="frame size (default 256x384)")
    times = p.add_mutually_exclusive_group()
    times.add_argument(
        "--times", metavar="T1,T2,...", help="exposure times in seconds (e.g. 1/500,1/125,1/30)"
    )
    times.add_argument(
        "--stops", type=float, metavar="N", help="stops between consecutive frames (default 2)"
    )
    p.add_argument("--frames", type=int, default=3, metavar="K", help="frames with --stops (3)")
    p.add_argument(
        "--base-time",
        default="1/256",
        metavar="T",
        help="shortest exposure with --stops, seconds (default 1/256)",
    )
    p.add_argument(
        "--bits",
        type=int,
        choices=(8, 10, 12, 14, 16),
        help="output bit depth (default 8; 12 for dng)",
    )
    p.add_argument(
        "--response", default="linear", choices=sorted(RESPONSES), help="camera response (linear)"
    )
    p.add_argument(
        "--noise",
        type=float,
        default=1.0,
        metavar="SIGMA",
        help="Gaussian noise in output levels (raw numbers for dng); default 1",
    )
    p.add_argument(
        "--shot-noise",
        type=float,
        default=None,
        metavar="FULLWELL",
        help="add photon shot noise for this full-well capacity (electrons at saturation)",
    )
    p.add_argument(
        "--shift",
        type=float,
        default=0.0,
        metavar="PX",
        help="hand-held motion: random shift of up to PX pixels per axis (reference: middle frame)",
    )
    p.add_argument(
        "--rotation",
        type=float,
        default=0.0,
        metavar="DEG",
        help="hand-held motion: random rotation of up to DEG degrees",
    )
    p.add_argument(
        "--key",
        type=float,
        default=None,
        metavar="K",
        help="exposure scale: a frame of time t records radiance * t * K (1.0 = saturation); "
        "default puts the median radiance at 0.18 for the geometric-mean time",
    )
    p.add_argument("--format", default="png", choices=sorted(FORMATS), help="file format (png)")
    p.add_argument(
        "--cfa",
        default="RGGB",
        choices=sorted(CFA_PATTERNS),
        help="colour filter array for dng (RGGB; XTRANS: Fujifilm's 6x6 cell)",
    )
    p.add_argument(
        "--sixteen-bit",
        default="scale",
        choices=("scale", "keep"),
        help="frames deeper than 8 bits in 16-bit PNG/TIFF: scale to 0..65535 (default) or keep",
    )
    p.add_argument(
        "--rendering",
        default="area",
        choices=("area", "log-cubic"),
        help="how frames are drawn from the scene: area (every pixel integrates the scene, "
        "motion keeps the brightness; default) or log-cubic (the earlier renderer: moved "
        "frames interpolated in log radiance, their brightness off by up to 1 %%)",
    )
    p.add_argument("--seed", type=int, default=0, help="scene, noise and motion seed (0)")
    p.add_argument("--force", action="store_true", help="replace existing files")
    p.add_argument("--json", action="store_true", help="print JSON on stdout")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    shape = parse_size(args.size)
    fmt = args.format
    bits = args.bits if args.bits is not None else (12 if fmt == "dng" else 8)
    if args.times is not None:
        times = parse_times(args.times)
    else:
        base = parse_times(args.base_time)
        if len(base) != 1:
            raise ParameterError("--base-time takes one time", found=args.base_time)
        times = bracket_times(2.0 if args.stops is None else args.stops, args.frames, base[0])
    if fmt == "dng" and args.response != "linear":
        raise ParameterError(
            "DNG frames need a linear response (RAW data is linear)",
            expected="--response linear",
            found=args.response,
        )
    if fmt == "jpeg" and bits != 8:
        raise ParameterError("JPEG holds 8-bit frames only", expected="--bits 8", found=str(bits))
    if args.shift < 0 or args.rotation < 0:
        raise ParameterError("--shift and --rotation are maxima and must be >= 0")
    if args.key is not None and not args.key > 0:
        raise ParameterError("--key must be positive", found=str(args.key))
    if args.shot_noise is not None and args.shot_noise <= 0:
        raise ParameterError("--shot-noise must be positive", found=str(args.shot_noise))

    sim = simulate_bracket(
        scene=args.scene,
        shape=shape,
        exposure_times=[float(t) for t in times],
        bits=bits,
        response=args.response,
        noise_sigma=args.noise,
        shot_noise_full_well=args.shot_noise,
        rendering=args.rendering,
        max_shift=args.shift,
        max_rotation_deg=args.rotation,
        seed=args.seed,
        key=args.key,
        keep_linear=fmt == "dng",
    )
    written = write_bracket(
        args.outdir,
        sim,
        fmt,
        force=args.force,
        sixteen_bit=args.sixteen_bit,
        cfa_pattern=args.cfa,
    )
    truth = sim.truth()
    out = {
        "directory": str(written.directory),
        "format": written.format,
        "scene": sim.scene,
        "shape": truth["shape"],
        "bits": sim.bits,
        "file_max_level": written.file_max_level,
        "response": sim.response,
        "key": sim.key,
        "frames": [
            {
                "file": str(path),
                "exposure_time": float(t),
                "exposure_time_exact": str(t),
                "to_reference": truth["to_reference"][k],
            }
            for k, (path, t) in enumerate(zip(written.frames, written.exposure_times, strict=True))
        ],
        "ratios": truth["ratios"],
        "pairs": truth["pairs"],
        "truth": str(written.truth),
        "exposure_times_file": str(written.times_file),
    }
    if args.json:
        print_json(out)
    else:
        for f in out["frames"]:
            print(f"{f['file']}  t={f['exposure_time_exact']} s")
        print(f"{out['truth']}")
        print(f"{out['exposure_times_file']}")
    return 0

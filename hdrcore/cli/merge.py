"""``hdrcore merge FILE... -o OUT.exr``: the whole method, end to end, with a JSON report.

Runs :class:`hdrcore.pipeline.Pipeline`: histograms -> exposure ratios (Cerman & Hlavac 2006,
section 5) -> response (non-linear input) -> registration (section 6) -> warp -> merge ->
preview. Every output path is checked before any work starts, outputs are written atomically,
inputs are never overwritten. Exit status: 0 merged; 1 merged, but a stage failed (e.g. a pair
could not be registered; the reason is printed and kept in the report); 2 bad input or refused
output; 3 internal error.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from concurrent.futures import ThreadPoolExecutor
from typing import Any

from ..errors import OutputError
from ..export import common_crop, crop_preview, write_result
from ..io import EXR_COMPRESSIONS, atomic_write, check_output_path, write_png
from ..io.bracket import Bracket
from ..merge.consistency import block_sums_bytes
from ..pipeline import Pipeline, ProgressCallback
from ._common import (
    add_bracket_arguments,
    check_outputs_first,
    input_files,
    load_bracket_from_args,
    print_json,
    to_jsonable,
)
from ._params import FLAGS, add_param_arguments, params_from_args

__all__ = ["MERGE_FIELDS", "add_parser", "run"]

#: the pipeline's parameters ``hdrcore merge`` offers (every one the command line has)
MERGE_FIELDS = tuple(FLAGS)

#: Verdicts that say a stage failed although the merge was written (exit status 1, the
#: report's ``status`` ``"stage-failed"``): a pair that could not be registered on a bracket
#: whose other pairs moved (a static bracket's unregistrable pair keeps the identity rightly,
#: ``registration-identity``, and is no failure).
STAGE_FAILED = frozenset({"registration-failed"})


#: The ghost test runs beside the outputs' writing when its block sums take at most this
#: (3 x 24 MP: 77 MiB, run beside); larger ones run before it, so their memory does not add to
#: the write's: 5 x 45 MP 14-bit (320 MiB of sums) peaked at 3088 MiB beside the write, over
#: the 3 GiB the issue allows, against 3010-3038 MiB one after the other.
BESIDE_WRITE_BYTES = 128 * 2**20


def add_parser(subparsers: argparse._SubParsersAction) -> None:
    p = subparsers.add_parser(
        "merge",
        help="merge a bracket into an OpenEXR radiance map (ratios, alignment, merge)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    add_bracket_arguments(p)
    add_param_arguments(p, MERGE_FIELDS, command="merge")
    p.add_argument("-o", "--output", required=True, metavar="OUT.exr", help="OpenEXR output")
    p.add_argument("--preview", metavar="OUT.png", help="also write a tonemapped 8-bit preview")
    p.add_argument("--report", metavar="OUT.json", help="write the JSON report of every stage")
    p.add_argument(
        "--dng",
        metavar="OUT.dng",
        help="also write the radiance map as a floating-point DNG 1.4 (LinearRaw "
        "camera RGB, black 0 / white 1) for a raw editor",
    )
    p.add_argument(
        "--dng-bits",
        dest="dng_bits",
        type=int,
        default=32,
        choices=(16, 32),
        help="float sample size of the DNG (default 32)",
    )
    p.add_argument(
        "--dng-layout",
        dest="dng_layout",
        default="auto",
        choices=("auto", "linear", "cfa"),
        help="DNG samples: cfa = the frames' mosaics merged before demosaicing "
        "(tripod RAW brackets), linear = demosaiced camera RGB (any bracket); "
        "auto picks cfa when it can (default)",
    )
    p.add_argument(
        "--crop",
        default="none",
        choices=("none", "common"),
        help="common: write the EXR and the preview cropped to the largest rectangle every "
        "frame covers (a hand-held bracket's border strips have fewer exposures; phones' "
        "locally tone-mapped frames leave bands there); default none",
    )
    p.add_argument("--float32", action="store_true", help="write float32 instead of half")
    p.add_argument(
        "--exr-compression",
        dest="exr_compression",
        default="piz",
        choices=sorted(EXR_COMPRESSIONS),
        help="lossless EXR compression (default piz: fast, small for photographs)",
    )
    p.add_argument("--force", action="store_true", help="replace existing output files")
    p.add_argument("--json", action="store_true", help="print the report on stdout")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    p.set_defaults(run=run)


class _Progress:
    """A one-line progress bar on a terminal (stderr); silent otherwise."""

    def __init__(self, enabled: bool) -> None:
        self.enabled = enabled and sys.stderr.isatty()
        self.t0 = time.perf_counter()

    def __call__(self, stage: str, fraction: float, message: str) -> None:
        if not self.enabled:
            return
        width = 24
        done = int(round(width * max(0.0, min(1.0, fraction))))
        bar = "#" * done + "-" * (width - done)
        dt = time.perf_counter() - self.t0
        sys.stderr.write(f"\r[{bar}] {stage:<12} {message[:40]:<40} {dt:6.1f}s")
        sys.stderr.flush()

    def close(self) -> None:
        if self.enabled:
            sys.stderr.write("\n")
            sys.stderr.flush()


def _release_mosaics(bracket: Bracket) -> int:
    """Drop the RAW frames' CFA mosaics (:attr:`Frame.cfa`); return the bytes let go.

    The command is the bracket's only user and runs the pipeline once: the mosaics are read by
    the noise estimate (memoized by the pipeline) and the registered pixel ratios (an input of
    the merge, so computed before it starts), never by the merge, the preview or the EXR. A
    24 MP 16-bit mosaic is 48 MB a frame, held beside the frame's demosaiced levels while the
    merge allocates its outputs: the command's peak memory."""
    freed = 0
    for frame in bracket.frames:
        if frame.cfa is not None:
            freed += frame.cfa.data.nbytes
            # Frames are frozen for the library's callers; this one owns the bracket.
            object.__setattr__(frame, "cfa", None)
    return freed


def _trim_heap() -> bool:
    """Give the free pages inside the heap back to the system (glibc ``malloc_trim``); ``True``
    if it ran.

    The program keeps freed memory for reuse (:mod:`hdrcore._memory`), so the process holds
    the high-water mark of the stages before the merge (the registered pixel ratios on the
    mosaics) in holes of many sizes. The merge's outputs fill some of them, and the ghost
    test's block sums (356 MiB at 45 MP) fit in none: on a 5 x 45 MP bracket the holes made
    the merge's peak 3.3 GB where what it uses is 3.0 GB. Called once the merge's outputs are
    written (its ``"ghost test"`` progress), so they reuse the kept pages; what is given back
    is only what they left free."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        import ctypes
        import ctypes.util

        libc = ctypes.CDLL(ctypes.util.find_library("c") or "libc.so.6")
        trim = libc.malloc_trim
    except (OSError, AttributeError):  # not glibc
        return False
    trim.argtypes = (ctypes.c_size_t,)
    trim.restype = ctypes.c_int
    trim(0)
    return True


def _releasing_mosaics(pipeline: Pipeline, progress: _Progress) -> ProgressCallback:
    """``progress``, which also releases the bracket's mosaics when the merge stage starts
    (its inputs, the pixel ratios among them, are then computed: the stage cache reports a
    stage once its inputs are ready) and gives the heap's free pages back when the merge's
    ghost test starts (:func:`_trim_heap`). The noise estimate is taken first."""
    pipeline.noise()
    released = trimmed = False

    def report(stage: str, fraction: float, message: str) -> None:
        nonlocal released, trimmed
        if stage == "merge" and not released:
            released = True
            _release_mosaics(pipeline.bracket)
        if stage == "merge" and message == "ghost test" and not trimmed:
            trimmed = True
            _trim_heap()
        progress(stage, fraction, message)

    return report


def run(args: argparse.Namespace) -> int:
    outputs = [args.output] + [p for p in (args.preview, args.report, args.dng) if p]
    if args.dng and not str(args.dng).lower().endswith(".dng"):
        raise OutputError(
            "the DNG output must be a .dng file", path=args.dng, expected="a name ending in .dng"
        )
    if not str(args.output).lower().endswith(".exr"):
        raise OutputError(
            "the HDR output must be an OpenEXR file",
            path=args.output,
            expected="a name ending in .exr",
        )
    if args.dng and args.crop != "none":
        raise OutputError(
            "--crop applies to the EXR and the preview, not to the DNG (a raw editor crops)",
            path=args.dng,
            expected="--crop none with --dng",
        )
    check_outputs_first(outputs, args)
    t_load = time.perf_counter()
    bracket = load_bracket_from_args(args)
    decode_seconds = time.perf_counter() - t_load
    # Frames, the times list and a response curve: no output may replace any of them.
    inputs = input_files(args, bracket.paths)
    for out in outputs:
        check_output_path(out, force=args.force, inputs=inputs)
    for w in bracket.warnings:
        print(f"hdrcore: warning: {w.message}", file=sys.stderr)

    params = params_from_args(args, MERGE_FIELDS, registration_previews=False)
    progress = _Progress(not args.quiet)
    # The command reads the merge's shares only through the report's summary (and the colour
    # check of non-linear input, for which the pipeline keeps them): the maps are not kept.
    pipeline = Pipeline(bracket, params, progress=progress, weight_maps=False)
    try:
        if not args.dng:
            # Only the DNG's CFA layout reads the mosaics after the merge has started.
            pipeline.progress = _releasing_mosaics(pipeline, progress)
        # The region ghost test (no pixel changes without --deghost) and a non-linear merge's
        # colour checks run on a thread of their own while the EXR, DNG and preview are
        # written: the write is mostly one thread.
        result = pipeline.run(until="preview" if args.preview else "merge", checks="later")
    except BaseException:
        progress.close()
        raise
    finishing = None
    if result.checks_pending:
        ghost = result.merge is not None and result.merge.ghost_test_pending
        if (
            ghost
            and result.merge is not None
            and block_sums_bytes(result.merge.radiance.shape, len(result.bracket))
            > BESIDE_WRITE_BYTES
        ):
            result = pipeline.finish_checks(result)  # before the write: peak memory
        else:
            ghost_thread = ThreadPoolExecutor(1, thread_name_prefix="hdrcore-checks")
            finishing = ghost_thread.submit(pipeline.finish_checks, result)
            ghost_thread.shutdown(wait=False)  # the one task still runs
    try:
        written = _write_outputs(args, result, inputs)
    finally:
        if finishing is not None:
            try:
                result = finishing.result()
            finally:
                progress.close()
        else:
            progress.close()
    report = result.to_report()
    failed = [v for v in result.verdicts if v.code in STAGE_FAILED]
    if report["status"] == "ok" and failed:
        report["status"] = "stage-failed"
    report["timings"]["decode"] = decode_seconds
    report["timings"]["write"] = written["write_seconds"]
    if written["crop"] is not None:
        report["crop"] = written["crop"]
    report["outputs"] = {
        "exr": args.output,
        "preview": args.preview,
        "report": args.report,
        "dng": args.dng,
        "dng_layout": written["layout"] if args.dng else None,
    }
    if args.report:
        text = json.dumps(to_jsonable(report), indent=2)
        atomic_write(args.report, lambda tmp: tmp.write_text(text), force=args.force, inputs=inputs)
    for v in result.verdicts:
        if v.severity in ("error", "warning"):
            print(f"hdrcore: {v.severity}: {v.message}", file=sys.stderr)
    if args.json:
        print_json(report)
    errors = [v for v in result.verdicts if v.severity == "error"]
    if errors:
        print(f"hdrcore: merge finished with errors: {errors[0].message}", file=sys.stderr)
        return 1
    if failed:
        print(
            f"hdrcore: merged, but a stage failed ({len(failed)} verdict"
            f"{'' if len(failed) == 1 else 's'} {failed[0].code}): the report's status is "
            "stage-failed",
            file=sys.stderr,
        )
        return 1
    return 0


def _write_outputs(args: argparse.Namespace, result: Any, inputs: Any) -> dict[str, Any]:
    """The EXR, the DNG and the preview PNG; returns the DNG's layout, the crop's report entry
    and the seconds spent."""
    t_write = time.perf_counter()
    crop = common_crop(result) if args.crop == "common" and result.radiance is not None else None
    if crop is not None and (crop[2] <= crop[0] or crop[3] <= crop[1]):
        raise OutputError(
            "no part of the image is covered by every frame: nothing to crop to",
            path=args.output,
            expected="frames that overlap",
            found="--crop common",
        )
    # The EXR is the radiance's last reader (the preview is made), unless a DNG follows.
    write_result(
        args.output,
        result,
        crop=crop,
        half=not args.float32,
        compression=args.exr_compression,
        force=args.force,
        inputs=inputs,
        overwrite_radiance=not args.dng,
    )
    dng_layout = None
    if args.dng:
        from ._dng import write_result_dng

        _, dng_layout = write_result_dng(
            args.dng,
            result,
            bits=args.dng_bits,
            layout=args.dng_layout,
            force=args.force,
            inputs=inputs,
        )
    if args.preview and result.preview is not None:
        image = result.preview.image
        if crop is not None:
            image = crop_preview(image, crop, result.preview_factor)
        write_png(args.preview, image, force=args.force, inputs=inputs)
    crop_entry = None
    if crop is not None:
        rows, cols = result.bracket.shape
        x0, y0, x1, y1 = crop
        crop_entry = {
            "rectangle": list(crop),
            "kept": round((x1 - x0) * (y1 - y0) / float(rows * cols), 4),
            "source": "common",
        }
    return {
        "layout": dng_layout,
        "crop": crop_entry,
        "write_seconds": time.perf_counter() - t_write,
    }

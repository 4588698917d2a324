"""Robustness on brackets people shoot (issue 12): exit codes, ok pairs, errors; HDRutils beside.

Every bracket is written by :mod:`hdrcore.synthetic.faults` (truth known) and run through the
``hdrcore`` commands as a user runs them, one subprocess per command (``python -m hdrcore.cli``):
``ratios --json``, ``align --json`` and ``merge -o out.exr --report r.json``, all with defaults.
A command that exits 2 (or crashes) is a row with that exit code, never a crash of the bench.
Tables, in one run:

1. **The seed's protocol** (Cerman & Hlavac 2006, section 5.3: 6 frames, times 1..1024 x4,
   linear, sigma = 1 level) at 8 and 12 bits (12-bit frames as scaled 16-bit PNG), over the
   scenes, tripod and hand-held (shifts up to 20 px, rotation up to 1 degree), normal key and
   dark scenes whose one or two shortest frames are black (``write_dark_scene``). Per case: the
   three exit codes; pairs reported ok and the median / max error of their ratios against the
   true times, from ``ratios --json`` and from the merge report's ``ratios`` (the ratios the
   merge used); ``sig``: of the pairs with signal in both frames (>= 1 % of the samples 5 sigma
   inside the range, noiseless truth), how many ``ratios`` reported ok; HDRutils ``cerman`` and
   ``mst`` (its PNG reader needs FreeImage, so its estimator runs on the decoded frames, RGGB
   mosaicked, after the frame screening its ``merge`` does): pairs estimated and median / max
   error. Targets (issue 12): every command exits 0 or 1; median error of ok pairs <= 0.1 % at
   8 bits and <= 0.01 % at 12 bits; no ok pair off by more than 1 %; every pair with signal
   measured.
2. **Faults** (8-bit PNG of the seed's protocol unless said): black first / middle frames (PNG,
   JPEG, DNG 12 and 14 bits), an all-saturated frame, a duplicate exposure, a times file (and
   EXIF) with two frames' times swapped, a tripod bracket whose darkest pairs have too little
   signal to register, a bracket with one usable frame (there exit 2 naming the others is the
   target). Per case the exit codes, the status of every pair, ok pairs more than 1 % off.
3. **Dark RAW**: the issue's 12-bit DNG bracket 2 stops apart whose darkest frame peaks at 1.5 %
   of the range (without margins, with masked margins and MaskedAreas, with ActiveArea only) and
   the 14-bit pair 6 stops apart; defaults and the issue's workaround ``--noise-floor 8``. Per
   case the exits, ok pairs and errors, the merged EXR's median radiance error against the
   simulator's radiance (one best scale factor: the median ratio) wherever some frame is well
   exposed (noiseless value 5..90 % of the range), the merge report's provenance (mean share
   and dominant fraction of the darkest frame) and, from the library's merge, the frame that
   dominates where every brighter frame is clipped and over the brightest 1 % of the scene;
   HDRutils ``merge`` on the same DNG files with ``estimate_exp`` ``cerman`` / ``mst``
   (ratios, and its merged radiance error on the same mask).

At the end, every distinct error message (numbers masked) with its count and one case, for the
engineers fixing the pipeline.

Usage: ``python bench/bench_robustness.py [--quick] [--jobs N] [--keep DIR]``.
``--quick``: 256x384 frames, one seed, dark scenes for two scenes only (32 seed-protocol cases,
13 faults, 8 dark RAW: 5 minutes on the shared 2-core machine with ``--jobs 1``). Full run:
512x768 seed-protocol frames, seeds 1 and 2, every scene normal and dark (96 cases): 17 minutes
with ``--jobs 1``. ``--only seed|faults|raw`` runs some tables. ``--keep DIR`` keeps the
brackets (one folder per case, with truth.json) to reproduce a row by hand.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import re
import subprocess
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Callable, Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from hdrcore.synthetic import (
    DARK_RAW_12BIT,
    SEED_PROTOCOL,
    WIDE_RAW_14BIT,
    FaultyBracket,
    write_black_frames,
    write_dark_raw_bracket,
    write_dark_scene,
    write_duplicate_exposure,
    write_one_usable_frame,
    write_reference_bracket,
    write_saturated_frame,
    write_swapped_times,
    write_unregistrable_tripod,
    write_wide_raw_pair,
)

os.environ.setdefault("TQDM_DISABLE", "1")  # HDRutils' progress bars

SCENES = ("landscape", "window", "night", "patches")
SIGNAL_MIN = 0.01  # a pair "has signal" with >= 1 % of its samples 5 sigma inside both frames
TARGET_MEDIAN = {8: 0.001, 12: 0.0001}
TARGET_MAX_OK = 0.01
COMMAND_TIMEOUT = 900.0


# ------------------------------------------------------------------------------ running hdrcore
@dataclass
class Outcome:
    """One ``hdrcore`` command: exit code (``None``: timeout), its JSON and first error line."""

    code: int | None
    doc: dict | None
    error: str
    seconds: float


def run_hdrcore(args: Sequence[str], *, json_file: Path | None = None) -> Outcome:
    """Run ``python -m hdrcore.cli ARGS``; the document is stdout's JSON or ``json_file``'s."""
    t0 = time.perf_counter()
    try:
        proc = subprocess.run(
            [sys.executable, "-m", "hdrcore.cli", *map(str, args)],
            capture_output=True,
            text=True,
            timeout=COMMAND_TIMEOUT,
        )
    except subprocess.TimeoutExpired:
        return Outcome(None, None, f"timeout after {COMMAND_TIMEOUT:g} s", time.perf_counter() - t0)
    doc = None
    try:
        if json_file is not None:
            if json_file.is_file():
                doc = json.loads(json_file.read_text())
        elif proc.stdout.strip():
            doc = json.loads(proc.stdout)
    except (json.JSONDecodeError, OSError):
        doc = None
    lines = [ln.strip() for ln in proc.stderr.splitlines() if ln.strip()]
    marks = ("hdrcore: error:", "internal error", "finished with errors", "Traceback")
    err = next((ln for ln in lines if any(m in ln for m in marks)), "")
    if not err and proc.returncode not in (0, 1) and lines:
        err = lines[-1]
    return Outcome(proc.returncode, doc, err.strip(), time.perf_counter() - t0)


@dataclass
class PairCheck:
    """A pair as a command reported it, against the truth (file-order indices)."""

    dark: int
    bright: int
    ratio: float
    true: float
    status: str

    @property
    def error(self) -> float:
        if not np.isfinite(self.ratio) or self.ratio <= 0:
            return float("inf")
        return abs(self.ratio / self.true - 1.0)

    @property
    def ok(self) -> bool:
        return self.status == "ok"


def check_pairs(doc: dict | None, case: FaultyBracket) -> list[PairCheck] | None:
    """The pairs of a ``ratios`` document (``{"frames", "pairs"}``) against the truth."""
    if not doc or "pairs" not in doc or "frames" not in doc:
        return None
    paths = [f.get("path") for f in doc["frames"]]
    out = []
    for p in doc["pairs"]:
        try:
            i = case.index_of(paths[p["dark"]])
            j = case.index_of(paths[p["bright"]])
        except (KeyError, IndexError, TypeError, ValueError):
            continue
        r = p.get("ratio")
        out.append(
            PairCheck(
                i,
                j,
                float("nan") if r is None else float(r),
                case.true_ratio(i, j),
                str(p.get("status")),
            )
        )
    return out


@dataclass
class PairStats:
    n: int = 0
    ok: int = 0
    errors: list[float] = field(default_factory=list)  # of the ok pairs
    signal: int = 0
    signal_ok: int = 0
    statuses: list[str] = field(default_factory=list)

    @property
    def bad_ok(self) -> int:
        return sum(e > TARGET_MAX_OK for e in self.errors)


def pair_stats(checks: list[PairCheck] | None, case: FaultyBracket) -> PairStats | None:
    """Counts over the reported pairs; ``signal``: the bracket's consecutive pairs (by true
    exposure) with signal in both frames, ``signal_ok``: how many of them were reported ok."""
    if checks is None:
        return None
    s = PairStats(n=len(checks))
    ok_pairs = set()
    for c in checks:
        s.statuses.append(c.status)
        if c.ok:
            s.ok += 1
            s.errors.append(c.error)
            ok_pairs.add((c.dark, c.bright))
    truth = case.pairs_with_signal(SIGNAL_MIN)
    s.signal = len(truth)
    s.signal_ok = sum(p in ok_pairs for p in truth)
    return s


def n_ok(doc: dict | None) -> str:
    if not doc or "pairs" not in doc:
        return "-"
    pairs = doc["pairs"]
    return f"{sum(p.get('status') == 'ok' for p in pairs)}/{len(pairs)}"


# ----------------------------------------------------------------------------------- HDRutils
class _Capture(logging.Handler):
    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.messages: list[str] = []

    def emit(self, record: logging.LogRecord) -> None:
        if record.levelno >= logging.WARNING:
            self.messages.append(record.getMessage())


def _quiet_hdrutils() -> _Capture:
    cap = _Capture()
    lg = logging.getLogger("HDRutils")
    lg.handlers[:] = [cap]
    lg.setLevel(logging.INFO)
    lg.propagate = False
    return cap


@dataclass
class PeerResult:
    """HDRutils on one bracket: ``(dark, bright, ratio)`` per pair it estimated (file order)."""

    pairs: list[tuple[int, int, float]]
    note: str
    hdr: np.ndarray | None = None


def _mosaic(frame: np.ndarray) -> np.ndarray:
    """RGGB mosaic: HDRutils' estimators read single-channel raw stacks (green at [::2, 1::2])."""
    h, w = frame.shape[0] // 2 * 2, frame.shape[1] // 2 * 2
    f = frame[:h, :w]
    m = np.empty((h, w), np.float32)
    m[0::2, 0::2] = f[0::2, 0::2, 0]
    m[0::2, 1::2] = f[0::2, 1::2, 1]
    m[1::2, 0::2] = f[1::2, 0::2, 1]
    m[1::2, 1::2] = f[1::2, 1::2, 2]
    return m


def _estimate(
    hx, Y: np.ndarray, exif: np.ndarray, meta: dict, method: str, floor: float, cap: _Capture
) -> tuple[np.ndarray | None, str]:
    """HDRutils' ``estimate_exposures``: the times, or ``None`` and why it gave up."""
    cap.messages.clear()
    try:
        exp = hx.estimate_exposures(Y, exif, meta, method, noise_floor=floor)
    except Exception as exc:  # a peer's failure is a result
        return None, f"{type(exc).__name__}: {exc}"[:100]
    if isinstance(exp, tuple):  # (exif, nan) when every tile was rejected
        return None, "; ".join(cap.messages)[:100] or "failed"
    reverted = [m for m in cap.messages if "Reverting" in m]
    if reverted:  # it then returns the EXIF times it was given, which would look perfect
        return None, reverted[0][:100]
    return np.asarray(exp, float), ""


def hdrutils_on_frames(case: FaultyBracket, method: str) -> PeerResult:
    """HDRutils' ``estimate_exposures`` on the decoded PNG/JPEG frames (its ``merge`` cannot read
    them: its PNG reader needs FreeImage), RGGB-mosaicked, after the frame screening of its
    ``merge`` (frames > 95 % saturated or at the floor are left out, estimation only with more
    than two frames). Noise floor: 5 sigma of the simulated noise in file levels (its ``merge``
    would take ``max(saturation / 1000, |min|)``, 0.25 levels on 8-bit frames, where its ratios
    come out hundreds of % off). When the whole stack fails (``mst`` needs valid pixels of every
    frame in each of its 16x16 tiles), it runs once per consecutive pair of the kept frames."""
    from hdrcore.io import load_frame

    try:
        import HDRutils.exposures as hx
    except ImportError as exc:
        return PeerResult([], f"not installed ({exc})")
    cap = _quiet_hdrutils()
    n = len(case.frames)
    # The file's values (16-bit PNG: 0..65535; Pillow would cut them to 8 bits).
    loaded = [load_frame(p) for p in case.frames]
    top = int(loaded[0].max_level)
    Y = np.stack([_mosaic(f.levels.astype(np.float32)) for f in loaded])
    exif = np.array(case.listed_times, float)
    meta = {
        "black_level": np.zeros(4),
        "h": Y.shape[1],
        "w": Y.shape[2],
        "saturation_point": 0.98 * top,
        "dtype": np.uint8 if top == 255 else np.uint16,
    }
    floor = 5.0 * case.spec.noise_sigma * top / ((1 << case.spec.bits) - 1)
    use = [
        i
        for i in range(n)
        if not (Y[i] >= meta["saturation_point"]).sum() > 0.95 * Y[i].size
        and not (Y[i] <= floor).sum() > 0.95 * Y[i].size
    ]
    notes = [f"frames {sorted(set(range(n)) - set(use))} screened out"] if len(use) < n else []
    if len(use) <= 2:
        return PeerResult([], "; ".join([*notes, f"not estimated: {len(use)} frame(s) kept"]))
    exp, why = _estimate(hx, Y[use], exif[use], meta, method, floor, cap)
    if exp is not None:
        pairs = [
            (a, b, float(exp[k + 1] / exp[k]))
            for k, (a, b) in enumerate(zip(use, use[1:], strict=False))
        ]
        return PeerResult(pairs, "; ".join(notes))
    pairs, fails = [], []
    for a, b in zip(use, use[1:], strict=False):
        e, w = _estimate(hx, Y[[a, b]], exif[[a, b]], meta, method, floor, cap)
        if e is None:
            fails.append(f"{a}-{b}")
        else:
            pairs.append((a, b, float(e[1] / e[0])))
    notes.append(f"stack failed ({why[:60]}); per pair" + (f", failed {fails}" if fails else ""))
    return PeerResult(pairs, "; ".join(notes))


def hdrutils_on_dng(case: FaultyBracket, method: str) -> PeerResult:
    """``HDRutils.merge`` on the DNG files (times given: the simulated DNGs carry no focal
    length, which its EXIF reader requires) with ``estimate_exp=method``."""
    try:
        import HDRutils
    except ImportError as exc:
        return PeerResult([], f"not installed ({exc})")
    cap = _quiet_hdrutils()
    n = len(case.frames)
    try:
        hdr, exif, est = HDRutils.merge(
            [str(p) for p in case.frames],
            exp=list(case.listed_times),
            gain=[1.0] * n,
            aperture=1.0,
            estimate_exp=method,
            return_exif_exp=True,
        )
    except Exception as exc:
        return PeerResult([], f"{type(exc).__name__}: {exc}"[:120])
    est = np.asarray(est, float)
    pairs = [(k, k + 1, float(est[k + 1] / est[k])) for k in range(n - 1)]
    notes = [
        re.sub(r"\S*/", "", m)
        for m in cap.messages  # file names, not paths
        if "Skipping" in m or "Reverting" in m or "failed" in m
    ]
    if np.array_equal(est, np.asarray(exif, float)):
        pairs = []
        notes.insert(0, "not estimated (EXIF returned: it estimates with > 2 usable frames)")
    return PeerResult(pairs, "; ".join(notes)[:160], hdr=np.asarray(hdr, np.float32))


def peer_stats(case: FaultyBracket, peer: PeerResult) -> tuple[int, int, list[float]]:
    """(pairs estimated, consecutive pairs of the bracket, errors of the estimated pairs)."""
    errs = [
        abs(r / case.true_ratio(a, b) - 1.0) if np.isfinite(r) and r > 0 else float("inf")
        for a, b, r in peer.pairs
    ]
    return len(errs), max(len(case.frames) - 1, 0), errs


# --------------------------------------------------------------------------------- formatting
def pct(v: float | None, digits: int = 3) -> str:
    if v is None or not np.isfinite(v):
        return "-"
    return f"{100 * v:.{digits}f}"


def code(o: Outcome | None) -> str:
    if o is None:
        return "-"
    return "T/O" if o.code is None else str(o.code)


def med_max(errs: Sequence[float]) -> tuple[float | None, float | None]:
    e = [x for x in errs if np.isfinite(x)]
    if not e:
        return None, None
    return float(np.median(e)), float(np.max(e))


MESSAGES: dict[str, list[str]] = defaultdict(list)


def remember(case_name: str, command: str, o: Outcome | None) -> None:
    if o is None or not o.error:
        return
    key = re.sub(r"\d+(\.\d+)?", "#", o.error)[:140]  # the same message, whatever the frames
    MESSAGES[f"{command} (exit {code(o)}): {key}"].append(f"{case_name}: {o.error}")


# ------------------------------------------------------------------------------------- a case
@dataclass
class CaseResult:
    name: str
    case: FaultyBracket | None
    ratios: Outcome | None = None
    align: Outcome | None = None
    merge: Outcome | None = None
    r_stats: PairStats | None = None
    m_stats: PairStats | None = None
    peers: dict[str, PeerResult] = field(default_factory=dict)
    extra: dict[str, Any] = field(default_factory=dict)
    failure: str = ""


def run_case(
    name: str,
    make: Callable[[Path], FaultyBracket],
    root: Path,
    *,
    peers: Sequence[str] = ("cerman", "mst"),
    extra_args: Sequence[str] = (),
    use_times_file: bool = False,
    align: bool = True,
) -> CaseResult:
    d = root / re.sub(r"[^A-Za-z0-9_.-]+", "_", name)
    try:
        case = make(d)
    except Exception as exc:
        return CaseResult(name, None, failure=f"generator: {type(exc).__name__}: {exc}")
    res = CaseResult(name, case)
    files = [str(p) for p in case.frames]
    common = [*files, *extra_args]
    if use_times_file:
        common += ["--times", str(case.times_file)]
    res.ratios = run_hdrcore(["ratios", *common, "--json"])
    if align:
        res.align = run_hdrcore(["align", *common, "--json"])
    report = d / "report.json"
    res.merge = run_hdrcore(
        ["merge", *common, "-o", d / "merged.exr", "--report", report, "--quiet", "--force"],
        json_file=report,
    )
    for cmd in ("ratios", "align", "merge"):
        remember(name, cmd, getattr(res, cmd))
    res.r_stats = pair_stats(check_pairs(res.ratios.doc, case), case)
    mdoc = res.merge.doc.get("ratios") if res.merge.doc else None
    res.m_stats = pair_stats(check_pairs(mdoc, case), case)
    for method in peers:
        if case.spec.fmt == "dng":
            res.peers[method] = hdrutils_on_dng(case, method)
        else:
            res.peers[method] = hdrutils_on_frames(case, method)
    return res


def run_all(jobs: Sequence[tuple], n_jobs: int) -> list[CaseResult]:
    if n_jobs <= 1:
        return [run_case(*j[:3], **(j[3] if len(j) > 3 else {})) for j in jobs]
    with ThreadPoolExecutor(n_jobs) as pool:
        futs = [pool.submit(run_case, *j[:3], **(j[3] if len(j) > 3 else {})) for j in jobs]
        return [f.result() for f in futs]


# ------------------------------------------------------------------------- 1. seed protocol
def seed_jobs(root: Path, quick: bool) -> list[tuple]:
    shape = (256, 384) if quick else (512, 768)
    seeds = (1,) if quick else (1, 2)
    jobs = []
    for bits in (8, 12):
        for motion in ("tripod", "hand-held"):
            for scene in SCENES:
                for seed in seeds:
                    spec = SEED_PROTOCOL.replace(
                        scene=scene,
                        shape=shape,
                        bits=bits,
                        seed=seed,
                        max_shift=20.0 if motion == "hand-held" else 0.0,
                        max_rotation_deg=1.0 if motion == "hand-held" else 0.0,
                    )
                    darks = (0, 1, 2) if not quick or scene in ("window", "patches") else (0,)
                    for n_black in darks:
                        name = f"{scene} {bits} {motion} dark{n_black} s{seed}"

                        def make(d: Path, spec=spec, n_black=n_black) -> FaultyBracket:
                            if n_black == 0:
                                return write_reference_bracket(d, spec)
                            return write_dark_scene(d, n_black, spec)

                        jobs.append((name, make, root, {"align": True}))
    return jobs


def codes_and_pair_columns(r: CaseResult) -> tuple[str, list[str]]:
    """Exit codes of ratios/align/merge, and the ok/measured, median and max error columns of
    the ratios and of the merge report."""
    codes = f"{code(r.ratios)} {code(r.align)} {code(r.merge)}"
    cols = []
    for s in (r.r_stats, r.m_stats):
        if s is None:
            cols.append(f"{'-':>9s} {'-':>7s} {'-':>7s}")
        else:
            m, x = med_max(s.errors)
            cols.append(f"{f'{s.ok}/{s.n}':>9s} {pct(m):>7s} {pct(x):>7s}")
    return codes, cols


def print_seed_table(results: list[CaseResult]) -> None:
    print(
        "\n== 1. Seed protocol (6 frames, times 1..1024 x4, linear, sigma 1 level): exit codes "
        "of ratios/align/merge; ok pairs and |error| % of their ratios from 'ratios --json' "
        "(the histograms alone: hand-held pairs are unstable there by design) and from the "
        "merge report (registered pixels); sig r/m: of the pairs with signal in both frames "
        "(truth), how many ratios / the merge reported ok; align: pairs registered ok; "
        "HDRutils: pairs estimated and |error| %"
    )
    hdr = (
        f"{'case':34s} {'r a m':>7s} | {'ratios ok':>9s} {'med%':>7s} {'max%':>7s} | "
        f"{'merge ok':>8s} {'med%':>7s} {'max%':>7s} | {'sig r/m':>8s} | {'align':>5s} | "
        f"{'cerman':>6s} {'med%':>6s} {'max%':>7s} | {'mst':>5s} {'med%':>6s} {'max%':>7s}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in results:
        if r.case is None:
            print(f"{r.name:34s} bench could not write the bracket: {r.failure}")
            continue
        codes, cols = codes_and_pair_columns(r)
        sig = "/".join("-" if s is None else f"{s.signal_ok}" for s in (r.r_stats, r.m_stats))
        sig += f" of {len(r.case.pairs_with_signal(SIGNAL_MIN))}"
        al = n_ok(r.align.doc if r.align else None)
        peers = []
        for method in ("cerman", "mst"):
            p = r.peers.get(method)
            if p is None:
                peers.append(f"{'-':>6s} {'-':>6s} {'-':>7s}")
                continue
            k, n, errs = peer_stats(r.case, p)
            m, x = med_max(errs)
            peers.append(f"{f'{k}/{n}':>6s} {pct(m, 2):>6s} {pct(x, 2):>7s}")
        print(
            f"{r.name:34s} {codes:>7s} | {cols[0]} | {cols[1][1:]} | "
            f"{sig:>8s} | {al:>5s} | {peers[0]} | {peers[1]}"
        )
    # Summary against the targets, per bit depth.
    print()
    for bits in (8, 12):
        rows = [r for r in results if r.case is not None and r.case.spec.bits == bits]
        if not rows:
            continue
        twos = {
            cmd: sum(
                getattr(r, cmd) is not None and getattr(r, cmd).code not in (0, 1) for r in rows
            )
            for cmd in ("ratios", "align", "merge")
        }
        for label, attr in (("ratios", "r_stats"), ("merge report", "m_stats")):
            errs = [e for r in rows if getattr(r, attr) for e in getattr(r, attr).errors]
            bad = sum(getattr(r, attr).bad_ok for r in rows if getattr(r, attr))
            sig = sum(len(r.case.pairs_with_signal(SIGNAL_MIN)) for r in rows)
            sig_ok = sum(getattr(r, attr).signal_ok for r in rows if getattr(r, attr))
            m, x = med_max(errs)
            verdict = []
            verdict.append(
                "exit ok"
                if sum(twos.values()) == 0
                else f"EXIT 2/3 in {twos['ratios']}/{twos['align']}/{twos['merge']} "
                "cases (ratios/align/merge)"
            )
            verdict.append(
                (
                    "median ok"
                    if m is not None and m <= TARGET_MEDIAN[bits]
                    else "MEDIAN OVER TARGET"
                )
                + f" ({pct(m)} % vs {pct(TARGET_MEDIAN[bits])})"
            )
            verdict.append("no ok pair > 1 %" if bad == 0 else f"{bad} OK PAIRS > 1 %")
            verdict.append(f"signal pairs ok {sig_ok}/{sig}")
            print(
                f"  {bits:2d} bits, {label:12s}: {len(rows)} cases, {len(errs)} ok pairs, "
                f"median {pct(m)} %, max {pct(x)} %: " + "; ".join(verdict)
            )


# --------------------------------------------------------------------------------- 2. faults
def fault_jobs(root: Path, quick: bool) -> list[tuple]:
    s = SEED_PROTOCOL.replace(seed=3)
    dng12 = s.replace(fmt="dng", bits=12, noise_sigma=2.0)
    dng14 = s.replace(fmt="dng", bits=14, noise_sigma=2.0)
    hand = s.replace(max_shift=20.0, max_rotation_deg=1.0)
    jobs = [
        ("black first (png 8)", lambda d: write_black_frames(d, 0, s)),
        ("black middle (png 8)", lambda d: write_black_frames(d, 2, s)),
        (
            "black first two (jpeg 8)",
            lambda d: write_black_frames(d, (0, 1), s.replace(fmt="jpeg")),
        ),
        ("black first (dng 12)", lambda d: write_black_frames(d, 0, dng12)),
        ("black middle (dng 14)", lambda d: write_black_frames(d, 3, dng14)),
        ("saturated last (png 8)", lambda d: write_saturated_frame(d, -1, s)),
        ("saturated middle (png 8)", lambda d: write_saturated_frame(d, 3, s)),
        ("duplicate exposure (png 8)", lambda d: write_duplicate_exposure(d, 2, s)),
        ("duplicate, hand-held (png 8)", lambda d: write_duplicate_exposure(d, 2, hand)),
        (
            "swapped times file 1<->2",
            lambda d: write_swapped_times(d, (1, 2), s),
        ),
        ("swapped EXIF times 1<->2", lambda d: write_swapped_times(d, (1, 2), s, in_exif=True)),
        ("unregistrable tripod (png 8)", lambda d: write_unregistrable_tripod(d, s)),
        ("one usable frame (png 8)", lambda d: write_one_usable_frame(d, 1)),
    ]
    out = []
    for name, make in jobs:
        opts: dict[str, Any] = {"peers": ()}
        if name.startswith("swapped times file"):
            opts["use_times_file"] = True
        out.append((name, make, root, opts))
    return out


def print_fault_table(results: list[CaseResult]) -> None:
    print(
        "\n== 2. Faults (seed protocol, 256x384 unless said): exit codes of ratios/align/"
        "merge (target: 0 or 1; 'one usable frame': 2 with a message naming the others); "
        "the status of each pair from ratios (file indices dark-bright); ok pairs > 1 % off"
    )
    print(
        f"{'case':30s} {'r a m':>7s} | {'ok >1%':>6s} | pairs (ratios --json): status, ratio "
        "vs true"
    )
    print("-" * 110)
    for r in results:
        if r.case is None:
            print(f"{r.name:30s} bench could not write the bracket: {r.failure}")
            continue
        codes = f"{code(r.ratios)} {code(r.align)} {code(r.merge)}"
        checks = check_pairs(r.ratios.doc if r.ratios else None, r.case)
        if checks is None:
            err = r.ratios.error if r.ratios else ""
            print(f"{r.name:30s} {codes:>7s} | {'-':>6s} | {err[:600]}")
            continue
        bad = sum(c.ok and c.error > TARGET_MAX_OK for c in checks)
        desc = ", ".join(
            f"{c.dark}-{c.bright} {c.status} {c.ratio:.4g}/{c.true:.4g}" for c in checks
        )
        print(f"{r.name:30s} {codes:>7s} | {bad:6d} | {desc}")
        if r.merge and r.merge.code not in (0, None) and r.merge.error:
            print(f"{'':30s} {'':>7s} | {'':>6s} | merge: {r.merge.error[:600]}")
        doc = r.merge.doc if r.merge else None
        if doc:
            codes_seen = Counter(
                f"{v.get('code')}({v.get('severity', '')[:4]})" for v in doc.get("verdicts", [])
            )
            listed = ", ".join(f"{c} x{n}" if n > 1 else c for c, n in codes_seen.items())
            print(f"{'':30s} {'':>7s} | {'':>6s} | merge verdicts: {listed or 'none'}")


# ------------------------------------------------------------------------------- 3. dark RAW
def _well_exposed(case: FaultyBracket) -> np.ndarray:
    """Samples where some frame's noiseless value lies in 5..90 % of the range (tripod)."""
    good = np.zeros(case.sim.linear_frames[0].shape, bool)
    for x in case.sim.linear_frames:
        good |= (x >= 0.05) & (x <= 0.90)
    return good


def radiance_error(
    rgb: np.ndarray | None, case: FaultyBracket, *, sites: bool = True
) -> float | None:
    """Median |merged / (s * truth) - 1| over the well-exposed samples, ``s`` the median ratio.

    ``sites``: only each pixel's own CFA colour (the value the sensor measured there; the
    demosaicer keeps it), which isolates the merge from the demosaicing error: on the textured
    scene, interpolated red and blue are about 3 % off, green 0.7 %, whatever the merge.
    """
    if rgb is None:
        return None
    from hdrcore.synthetic.dng import cfa_channel_map

    truth = case.sim.radiance.astype(np.float64)
    if rgb.shape != truth.shape:
        return None
    mask = _well_exposed(case) & np.isfinite(rgb) & (rgb > 0)
    if sites:
        own = cfa_channel_map("RGGB", truth.shape[:2])[..., None] == np.arange(3)
        mask &= own
    if not mask.any():
        return None
    q = rgb[mask].astype(np.float64) / truth[mask]
    s = float(np.median(q))
    return float(np.median(np.abs(q / s - 1.0)))


def library_provenance(case: FaultyBracket, extra_args: Sequence[str]) -> dict[str, Any]:
    """Which frame the library's merge takes where only the darkest frame is unclipped and over
    the brightest 1 % of the scene (shares are not in the report)."""
    from hdrcore.io import load_bracket
    from hdrcore.merge.maps import dominant_frame
    from hdrcore.pipeline import Pipeline, PipelineParams

    floor = None
    if "--noise-floor" in extra_args:
        floor = float(extra_args[list(extra_args).index("--noise-floor") + 1])
    try:
        br = load_bracket([str(p) for p in case.frames])
        res = Pipeline(br, PipelineParams(noise_floor=floor, registration_previews=False)).run(
            until="merge"
        )
    except Exception as exc:
        return {"error": f"{type(exc).__name__}: {exc}"[:120]}
    if res.merge is None:
        return {"error": "no merge"}
    order = [case.index_of(f.meta.path) for f in br.frames]
    dom = np.asarray(dominant_frame(res.merge.shares))
    dom_file = np.asarray(order)[dom]
    lum = case.sim.radiance.mean(axis=2)
    top = lum >= np.quantile(lum, 0.99)
    darkest = int(np.argmin(case.exposure_times))
    others = [k for k in range(len(case.frames)) if k != darkest]
    clipped = np.ones(lum.shape, bool)
    for k in others:
        clipped &= case.sim.linear_frames[k].min(axis=2) >= 1.0
    out: dict[str, Any] = {"top1_dominant": Counter(dom_file[top].tolist()).most_common(1)[0]}
    out["top1_darkest_share"] = float(np.mean(dom_file[top] == darkest))
    out["only_darkest_unclipped"] = float(clipped.mean())
    if clipped.any():
        out["there_darkest_share"] = float(np.mean(dom_file[clipped] == darkest))
    return out


def raw_jobs(root: Path, quick: bool) -> list[tuple]:
    shape = (256, 384) if quick else (512, 768)
    d12 = DARK_RAW_12BIT.replace(shape=shape, seed=5)
    d14 = WIDE_RAW_14BIT.replace(shape=shape, seed=5)
    variants = [
        ("12-bit 2 stops peak 1.5 %", lambda d: write_dark_raw_bracket(d, d12)),
        ("  + margins, MaskedAreas", lambda d: write_dark_raw_bracket(d, d12.replace(margins=16))),
        (
            "  + margins, ActiveArea only",
            lambda d: write_dark_raw_bracket(d, d12.replace(margins=16, masked_areas=False)),
        ),
        ("14-bit pair 6 stops", lambda d: write_wide_raw_pair(d, d14)),
        ("  + margins, MaskedAreas", lambda d: write_wide_raw_pair(d, d14.replace(margins=16))),
    ]
    jobs = []
    for k, (name, make) in enumerate(variants):
        jobs.append((f"{name}", make, root / f"raw{k}", {"align": True}))
        if not name.startswith(" "):  # the workaround, beside the defaults
            jobs.append(
                (
                    f"{name}, --noise-floor 8",
                    make,
                    root / f"raw{k}-floor8",
                    {"align": True, "extra_args": ("--noise-floor", "8"), "peers": ()},
                )
            )
    return jobs


def print_raw_table(results: list[CaseResult]) -> None:
    print(
        "\n== 3. Dark RAW (DNG, read noise 2 DN, 'patches' scene): exit codes; ok pairs and "
        "|error| % (ratios --json; merge report); merged EXR median radiance |error| % where "
        "some frame is well exposed (target <= 1 %), at each pixel's own CFA colour (rad) and "
        "over all samples, demosaicing included (all); provenance (report: darkest frame's mean "
        "share / dominant fraction; library merge: share of the brightest 1 % and of the "
        "samples where only the darkest frame is unclipped that the darkest frame dominates); "
        "HDRutils merge (cerman / mst): pairs estimated, ratio |error| %, radiance |error| %"
    )
    hdr = (
        f"{'case':44s} {'r a m':>7s} | {'ratios ok':>9s} {'med%':>7s} {'max%':>7s} | "
        f"{'merge ok':>8s} {'med%':>7s} {'max%':>7s} | {'rad%':>6s} {'all%':>5s} | "
        f"{'prov':>11s} | {'top1%':>5s} {'only':>11s}"
    )
    print(hdr)
    print("-" * len(hdr))
    for r in results:
        if r.case is None:
            print(f"{r.name:44s} bench could not write the bracket: {r.failure}")
            continue
        codes, cols = codes_and_pair_columns(r)
        rad = r.extra.get("rad")
        prov = "-"
        doc = r.merge.doc if r.merge else None
        if doc and doc.get("merge") and doc["merge"].get("provenance"):
            pv = doc["merge"]["provenance"]
            darkest_sorted = 0  # the report lists frames darkest first
            prov = (
                f"{pv['mean_share'][darkest_sorted]:.3f}/"
                f"{pv['dominant_fraction'][darkest_sorted]:.3f}"
            )
        lp = r.extra.get("prov", {})
        top = "-" if "top1_darkest_share" not in lp else f"{lp['top1_darkest_share']:.2f}"
        only = "-"
        if "only_darkest_unclipped" in lp:
            share = lp.get("there_darkest_share")
            only = (
                f"{'-' if share is None else f'{share:.2f}'} of "
                f"{100 * lp['only_darkest_unclipped']:.1f}%"
            )
        print(
            f"{r.name:44s} {codes:>7s} | {cols[0]} | {cols[1][1:]} | {pct(rad, 2):>6s} "
            f"{pct(r.extra.get('rad_all'), 2):>5s} | {prov:>11s} | {top:>5s} {only:>11s}"
        )
        if "error" in lp:
            print(f"{'':44s} library merge: {lp['error']}")
        for method in ("cerman", "mst"):
            p = r.peers.get(method)
            if p is None:
                continue
            k, n, errs = peer_stats(r.case, p)
            m, x = med_max(errs)
            prad = radiance_error(p.hdr, r.case)
            pall = radiance_error(p.hdr, r.case, sites=False)
            print(
                f"{'':44s} HDRutils {method:6s}: {k}/{n} estimated, median {pct(m)} %, max "
                f"{pct(x)} %, radiance {pct(prad, 2)} % (all {pct(pall, 2)} %)"
                + (f"  ({p.note})" if p.note else "")
            )
    print(
        "  note: 2 stops apart, a darkest frame peaking at 1.5 % leaves the next frame at 6 %, "
        "unclipped: an SNR-weighted merge takes the highlights from the brighter frames; the "
        "darkest frame can carry only what every brighter frame clips ('only' column)."
    )


def finish_raw(results: list[CaseResult]) -> None:
    """Radiance error of our EXR and the library merge's provenance, per dark-RAW case."""
    from hdrcore.io.exr import read_exr

    for r in results:
        if r.case is None:
            continue
        exr = r.case.directory / "merged.exr"
        if r.merge and r.merge.code in (0, 1) and exr.is_file():
            try:
                rgb, _ = read_exr(exr)
                rgb = np.asarray(rgb, np.float64)
                r.extra["rad"] = radiance_error(rgb, r.case)
                r.extra["rad_all"] = radiance_error(rgb, r.case, sites=False)
            except Exception as exc:
                r.extra["rad_error"] = f"{type(exc).__name__}: {exc}"
        extra_args = ("--noise-floor", "8") if "noise-floor" in r.name else ()
        r.extra["prov"] = library_provenance(r.case, extra_args)


# ----------------------------------------------------------------------------------------- main
def main(argv: Sequence[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--quick", action="store_true", help="small frames, one seed, fewer scenes")
    ap.add_argument("--jobs", type=int, default=1, help="cases run at once (default 1)")
    ap.add_argument("--keep", metavar="DIR", help="write the brackets here and keep them")
    ap.add_argument(
        "--only",
        choices=("seed", "faults", "raw"),
        action="append",
        help="run only these tables (repeatable)",
    )
    args = ap.parse_args(argv)
    tables = set(args.only or ("seed", "faults", "raw"))
    t0 = time.perf_counter()
    with tempfile.TemporaryDirectory(prefix="bench_robustness_") as tmp:
        root = Path(args.keep) if args.keep else Path(tmp)
        root.mkdir(parents=True, exist_ok=True)
        print(
            f"bench_robustness: {'quick' if args.quick else 'full'} run, jobs {args.jobs}, "
            f"brackets in {root}{'' if args.keep else ' (deleted at the end)'}"
        )
        if "seed" in tables:
            res = run_all(seed_jobs(root / "seed", args.quick), args.jobs)
            print_seed_table(res)
        if "faults" in tables:
            res = run_all(fault_jobs(root / "faults", args.quick), args.jobs)
            print_fault_table(res)
        if "raw" in tables:
            res = run_all(raw_jobs(root / "raw", args.quick), args.jobs)
            finish_raw(res)
            print_raw_table(res)
        print("\n== Error messages (numbers masked), with their count and one case")
        if not MESSAGES:
            print("  none")
        for key, where in sorted(MESSAGES.items(), key=lambda kv: -len(kv[1])):
            print(f"  [{len(where):3d}] {key[:220]}")
            print(f"        e.g. {where[0][:220]}")
    print(f"\ntotal {time.perf_counter() - t0:.0f} s")
    return 0


if __name__ == "__main__":
    sys.exit(main())

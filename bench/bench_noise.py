"""The noise floor measured from the noise (issue 12): how well sigma is measured, and what the
floor does to the ratios and the merge on the real brackets of ../shared/data.

Tables:

1. Simulated DNG brackets (12 and 14 bits, read noise 1-4 DN), with and without masked
   optical-black margins: the sigma the pipeline measures against the truth, the floor it sets
   and the old default (2 % of the range).
2. Real brackets: the sigma measured per frame and the floor; then, for a range of floors
   (explicit ``--noise-floor``, pedestal not added), the pairs reported ok, the median and the
   largest error of the measured ratios against the bracket's own times (APEX-snapped EXIF, or
   its exposure_times.txt), and the merge's ghost fraction. The non-linear minimum of
   ``hdrcore.noise`` (2 % of the range for 8-bit frames) is chosen from this table.

    python bench/bench_noise.py [--quick]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from hdrcore.io import load_bracket  # noqa: E402
from hdrcore.pipeline import Pipeline, PipelineParams  # noqa: E402
from hdrcore.synthetic import faults  # noqa: E402

DATA = (ROOT / ".." / "shared" / "data").resolve()

REAL = {
    "memorial": (
        "memorial-debevec",
        "exposure_times.txt",
        dict(exclude_colour=(0, 0, 255), align="none"),
    ),
    "frobisher": ("frobisher-colour-hdri", None, {}),
    "pixel7": ("handheld-pixel7-lab", None, dict(registration_max_pixels=3_000_000)),
}
#: Floors tried beside the fixed ones: memorial's scans sit on a film-base pedestal at level 16,
#: so its default is 16 + 5.1; 16 + 2.55 is what a 1 % minimum would give.
EXTRA_FLOORS = {"memorial": (16.0 + 2.55, 16.0 + 8.0)}


def simulated(quick: bool) -> None:
    print("\n## Simulated DNG brackets: measured read noise (DN) and the floor")
    print(
        f"{'bits':>4} {'true sigma':>10} {'margins':>8} {'measured':>9} {'source':>14} "
        f"{'floor':>7} {'old floor':>9}"
    )
    sigmas = (1.0, 3.0) if quick else (1.0, 2.0, 4.0)
    for bits in (12, 14):
        for sigma in sigmas:
            for margins in (None, 16):
                spec = faults.DARK_RAW_12BIT.replace(
                    bits=bits, noise_sigma=sigma, margins=margins, shape=(192, 288)
                )
                with tempfile.TemporaryDirectory() as d:
                    fb = faults.write_dark_raw_bracket(Path(d) / "b", spec=spec)
                    pipe = Pipeline(load_bracket([fb.directory]))
                    n = pipe.noise()
                    old = max(3.0, 0.02 * pipe.bracket.max_level)
                    print(
                        f"{bits:>4} {sigma:>10.2f} {('yes' if margins else 'no'):>8} "
                        f"{n.sigma:>9.3f} {n.source:>14} {pipe.auto_noise_floor():>7.2f} "
                        f"{old:>9.1f}"
                    )


def _true_times(b, times_file):
    if times_file is not None:
        return np.array([float(f.meta.exposure_time) for f in b.frames])
    return np.array([float(e) for e in b.exif_exposures(snapped=True)])


def real(quick: bool) -> None:
    if not DATA.is_dir():
        print(f"\n(real brackets skipped: {DATA} not found)")
        return
    floors = (None, 3, 5, 8) if quick else (None, 2, 3, 5, 8, 12)
    for name, (folder, times_name, kw) in REAL.items():
        d = DATA / folder
        if not d.is_dir():
            continue
        files = sorted(p for p in d.iterdir() if p.suffix.lower() in (".jpg", ".png"))
        b = load_bracket(files, exposure_times=None if times_name is None else d / times_name)
        pipe = Pipeline(b)
        n = pipe.noise()
        print(
            f"\n## {name}: sigma per frame (levels) "
            + ", ".join(f"{f.sigma:.2f}" for f in n.frames)
            + f"; default floor {pipe.auto_noise_floor(kw.get('exclude_colour')):.2f}"
        )
        truth = _true_times(b, times_name)
        print(
            f"{'floor':>7} {'ok pairs':>9} {'median err %':>12} {'max err %':>10} "
            f"{'ghost %':>8} {'seconds':>8}"
        )
        for floor in floors + EXTRA_FLOORS.get(name, ()):
            t0 = time.perf_counter()
            r = pipe.run(
                PipelineParams(
                    noise_floor=floor, preview_max_side=400, registration_previews=False, **kw
                ),
                until="merge",
            )
            errs, ok = [], 0
            for p in r.exposures.pairs:
                if not np.isfinite(p.ratio):
                    continue
                i = b.frames.index(r.bracket.frames[p.dark])
                j = b.frames.index(r.bracket.frames[p.bright])
                errs.append(abs(p.ratio / (truth[j] / truth[i]) - 1))
                ok += p.ok
            med = 100 * float(np.median(errs)) if errs else float("nan")
            mx = 100 * float(np.max(errs)) if errs else float("nan")
            print(
                f"{r.noise_floor:>7.2f} {ok:>4}/{len(r.exposures.pairs):<4} {med:>12.3f} "
                f"{mx:>10.3f} {100 * float(r.merge.ghost.mean()):>8.1f} "
                f"{time.perf_counter() - t0:>8.1f}"
            )


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="fewer cases")
    args = ap.parse_args()
    simulated(args.quick)
    real(args.quick)


if __name__ == "__main__":
    main()

"""Which stages a control of the inspector re-runs, and what the cache saves (issue 17, point 1).

For each control of ``hdrview`` (the parameter it sets), the pipeline is first run with the
defaults, then with that one parameter changed, the way the inspector does it: a run until the
ratios (the quick redraw of the BTF plot and the masks), then the full run. The table lists the
stages each of the two runs computed (the rest came from the cache), the full run's wall and
CPU seconds beside a fresh pipeline's (no cache) on the same parameters, and whether every
cached result equals the fresh one (radiance and preview bit for bit).

    python bench/bench_stage_graph.py [--only sim|real] [--json out.json]

Timings are of a shared machine: read them with the CPU column and repeat a timing that matters.
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))


from hdrcore.io import load_bracket  # noqa: E402
from hdrcore.pipeline import Pipeline  # noqa: E402

DATA = Path("/work/shared/data")


def controls(res) -> list[tuple[str, dict, dict]]:
    """One change per inspector control (hdrview.session.Controls), from the defaults (and
    the sliders once more with alignment off): (control, base changes, change)."""
    p = res.params
    off = {"align": "none"}
    return [
        (name, {}, change)
        for name, change in [
            ("saturation", {"saturation": float(p.saturation) * 0.9}),
            ("noise_floor", {"noise_floor": float(p.noise_floor) + 2.0}),
            ("threshold", {"threshold": 0.15}),
            ("alignment", {"align": "similarity" if p.align != "similarity" else "shift"}),
            ("local", {"local": "off"}),
            ("reference", {"reference": 0}),
            ("response", {"response": "srgb"}),
            ("times", {"times": "exif"}),
            ("exposure_method", {"exposure_method": "Cerman 2006"}),
            ("tonemap", {"tonemap": "reinhard" if p.tonemap != "reinhard" else "aces"}),
            ("exposure", {"tonemap_exposure": 1.0}),
            ("deghost", {"deghost": True}),
        ]
    ] + [
        (f"{name} (align none)", off, change)
        for name, change in [
            ("saturation", {"saturation": float(p.saturation) * 0.9}),
            ("noise_floor", {"noise_floor": float(p.noise_floor) + 2.0}),
            ("threshold", {"threshold": 0.15}),
            ("exposure", {"tonemap_exposure": 1.0}),
        ]
    ]


def equal(a, b) -> bool:
    """Every array and number of two pipeline results equal (timings left out)."""
    from tests.pipeline._compare import differences

    return not differences(a, b)


def brackets(only: str | None) -> list[tuple[str, object]]:
    out = []
    if only in (None, "sim"):
        from hdrcore.synthetic import simulate_bracket, write_bracket

        sim = simulate_bracket(
            scene="window",
            shape=(320, 480),
            exposure_times=(1 / 64, 1 / 16, 1 / 4),
            bits=8,
            response="gamma",
            noise_sigma=1.0,
            max_shift=4,
            max_rotation_deg=0.5,
            seed=3,
        )
        tmp = Path(tempfile.mkdtemp(prefix="bench_stage_graph_"))
        write_bracket(tmp, sim, fmt="png")
        out.append(("simulated hand-held 480x320 PNG", load_bracket([tmp])))
    if only in (None, "real") and (DATA / "frobisher-colour-hdri").is_dir():
        out.append(("frobisher 640x426 JPEG", load_bracket([DATA / "frobisher-colour-hdri"])))
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--only", choices=("sim", "real"))
    ap.add_argument("--json", type=Path)
    args = ap.parse_args()
    rows = []
    for name, bracket in brackets(args.only):
        base = Pipeline(bracket).run()
        print(f"\n{name}: defaults ran {', '.join(base.stages_run)}")
        print(
            "| control | parameter | quick run (until ratios) | full run | cached wall / CPU s "
            "| fresh wall / CPU s | equal to fresh |"
        )
        print("|---|---|---|---|---|---|---|")
        for control, start, change in controls(base):
            pipe = Pipeline(bracket)
            p0 = base.params.replace(**start)
            pipe.run(p0)
            p = p0.replace(**change)
            try:
                quick = pipe.run(p, until="ratios")
                w0, c0 = time.perf_counter(), time.process_time()
                full = pipe.run(p)
                w1, c1 = time.perf_counter(), time.process_time()
                fresh = Pipeline(bracket).run(p)
                w2, c2 = time.perf_counter(), time.process_time()
            except Exception as exc:  # a change the bracket cannot take (no EXIF times)
                print(f"| {control} | {change} | - | {type(exc).__name__}: {exc} | | | |")
                continue
            same = equal(full, fresh)
            row = dict(
                bracket=name,
                control=control,
                change={k: str(v) for k, v in change.items()},
                quick=list(quick.stages_run),
                full=list(full.stages_run),
                cached_wall=w1 - w0,
                cached_cpu=c1 - c0,
                fresh_wall=w2 - w1,
                fresh_cpu=c2 - c1,
                equal=same,
            )
            rows.append(row)
            print(
                f"| {control} | {', '.join(f'{k}={v}' for k, v in row['change'].items())} "
                f"| {', '.join(quick.stages_run) or '-'} | {', '.join(full.stages_run) or '-'} "
                f"| {w1 - w0:.2f} / {c1 - c0:.2f} | {w2 - w1:.2f} / {c2 - c1:.2f} "
                f"| {'yes' if same else 'NO'} |"
            )
    if args.json:
        args.json.write_text(json.dumps(rows, indent=1))


if __name__ == "__main__":
    main()

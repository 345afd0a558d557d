"""RESTframe benchmark suite (issue 7): accuracy, stability and speed, written to docs/benchmarks.md.

    tools/dev.sh tests/bench/run.py            # the full report (docs/benchmarks.md + docs/bench/*.png)
    tools/dev.sh tests/bench/run.py --smoke    # tiny sizes, a few seconds (CI keeps it alive)

Options: ``--out FILE`` (report path; plots go to ``bench/`` beside it), ``--only 1,3``
(sections to run).  Timings are ratios measured in this one run (see bench_common).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import os
import platform
import sys
import time
import traceback
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

import matplotlib  # noqa: E402

matplotlib.use("Agg")

import numpy as np  # noqa: E402

from bench_common import ROOT, Context, Section, load  # noqa: E402

SECTIONS = {
    "1": "bench_knobs",
    "2": "bench_stability",
    "3": "bench_throughput",
    "4": "bench_frugal",
    "5": "bench_cycles",
    "6": "bench_build",
    "7": "bench_path_cycles",
    "8": "measure_lens",
    "9": "bench_per_sample",
    "10": "bench_parallel",
    "11": "bench_persistent",
}


def machine() -> str:
    cpu = "?"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                cpu = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    import embreex

    return (f"{cpu}, {os.cpu_count()} logical cores; Python {platform.python_version()}, numpy {np.__version__}, "
            f"embreex {getattr(embreex, '__version__', '?')}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--smoke", action="store_true", help="tiny sizes: checks that the suite runs, numbers are not meaningful")
    parser.add_argument("--out", default=str(ROOT / "docs" / "benchmarks.md"), help="report path")
    parser.add_argument("--only", default="", help="comma-separated section numbers (default: all)")
    args = parser.parse_args(argv)

    out = Path(args.out).resolve()
    plots = out.parent / "bench"
    plots.mkdir(parents=True, exist_ok=True)
    ctx = Context(smoke=args.smoke, out_dir=plots, plot_prefix="bench",
                  log=lambda *a: print(*a, file=sys.stderr, flush=True))
    wanted = [s.strip() for s in args.only.split(",") if s.strip()] or list(SECTIONS)
    command = "tools/dev.sh tests/bench/run.py" + (" --smoke" if args.smoke else "") + \
        (f" --only {args.only}" if args.only else "")

    load_start = os.getloadavg()
    started = time.perf_counter()
    sections: list[Section] = []
    failed = []
    for key in wanted:
        module = __import__(SECTIONS[key])
        ctx.log(f"section {key} ({SECTIONS[key]}), load {load():.2f}")
        t0 = time.perf_counter()
        try:
            sec = module.run(ctx)
        except Exception:  # a broken section is reported, the others still run
            failed.append(key)
            sec = Section(f"{key}. {SECTIONS[key]}: FAILED")
            sec.add("```")
            sec.add(traceback.format_exc())
            sec.add("```")
        sec.seconds = time.perf_counter() - t0
        sections.append(sec)
    load_end = os.getloadavg()
    total = time.perf_counter() - started

    lines = ["# RESTframe benchmarks", ""]
    if args.smoke:
        lines += ["**Smoke run: tiny sizes, the numbers are not meaningful.**", ""]
    lines += [
        "Accuracy, stability and speed of the RESTframe core (issue 7), all from one run of",
        "",
        f"    {command}",
        "",
        f"- Date: {datetime.datetime.now().strftime('%Y-%m-%d %H:%M')}; run time {total:.0f} s.",
        f"- Machine: {machine()}.",
        f"- Load average (1, 5, 15 min) at the start {load_start[0]:.2f}, {load_start[1]:.2f}, {load_start[2]:.2f}; "
        f"at the end {load_end[0]:.2f}, {load_end[1]:.2f}, {load_end[2]:.2f}. The machine is shared, so "
        "absolute times vary: every comparison is a ratio of times taken in this run, interleaved "
        "(A, B, A, B, ...) with the minimum over repeats taken for each side.",
        "",
        "## Goals",
        "",
        "| goal | target | measured | met |",
        "|---|---|---|---|",
    ]
    for sec in sections:
        for g in sec.goals:
            met = "n/a" if g.met is None else ("**yes**" if g.met else "**no**")
            lines.append(f"| {g.name} | {g.target} | {g.measured} | {met} |")
    lines += ["", "Where a speed goal is missed, its cause and the speed work done so far (before and after): "
              "[speed.md](speed.md).", ""]
    for sec in sections:
        lines += [f"## {sec.title}", "", *sec.body, "", f"*(section time {sec.seconds:.0f} s)*", ""]
    out.write_text("\n".join(lines) + "\n")

    numbers = {f"{i}.{k}": v for sec, i in zip(sections, wanted) for k, v in sec.numbers.items()}
    (plots / ("numbers-smoke.json" if args.smoke else "numbers.json")).write_text(json.dumps(numbers, indent=1, sort_keys=True))
    bad = [k for k, v in numbers.items() if not math.isfinite(v)]
    ctx.log(f"wrote {out} ({len(numbers)} numbers, {total:.0f} s)")
    if failed:
        ctx.log(f"sections failed: {failed}")
    if bad:
        ctx.log(f"non-finite numbers: {bad}")
    return 1 if failed or bad else 0


if __name__ == "__main__":
    sys.exit(main())

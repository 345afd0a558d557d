"""The benchmark suite in --smoke mode: it runs end to end and writes a report with finite numbers.

No timing assertions: the smoke sizes are too small to mean anything, this only keeps the
suite from rotting (the real report is ``tools/dev.sh tests/bench/run.py``).
"""

import json
import math
import os
import subprocess
import sys
from pathlib import Path

RUN = Path(__file__).with_name("run.py")


def test_benchmark_suite_smoke_run(tmp_path):
    report = tmp_path / "benchmarks.md"
    done = subprocess.run([sys.executable, str(RUN), "--smoke", "--out", str(report)], capture_output=True, text=True,
                          cwd=RUN.parents[2], timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    text = report.read_text()
    for heading in ("## Goals", *(f"## {section}. " for section in range(1, 12))):
        assert heading in text, heading
    assert "FAILED" not in text
    assert text.count("bit-identical to threads x1: True") == 2  # section 10, each scene
    goals = text.split("## Goals", 1)[1].split("\n## ", 1)[0].splitlines()
    cores = os.cpu_count() or 1
    issue_20 = {  # each of issue 20's "done when" ratios, once in the goals (the machine's own scaling beside the two-core ones)
        "render / raw Embree replay of its own queries": 1,
        "1536^2, 1 thread: F12 / raw Embree build + trace": 1,
        f"1536^2, {cores} threads: F12 / raw Embree build + trace": int(cores > 1),
        "two cores / one core, worker processes, moving_sphere": 1,
        "two cores / one core, worker processes, bars_sideways": 1,
        "the machine's own two-process scaling in the same run": 2,
        "strict serial share projected to 16 cores": 2,
        "frames 2..N / frame 1 with persistent data, 11x11 bars": 1,
        "-triangle sphere (frames": 1,
        "rest-frame build / Embree's build of the same triangles": 1,
        "11 frames vs 1 frame (11x11 bars, render)": 1,
    }
    for name, count in issue_20.items():
        assert sum(name in line for line in goals) == count, name
    numbers = json.loads((tmp_path / "bench" / "numbers-smoke.json").read_text())
    assert len(numbers) > 40
    assert all(math.isfinite(v) for v in numbers.values())
    for plot in ("knobs.png", "stability.png", "throughput.png", "cycles.png", "path_cycles.png"):
        assert (tmp_path / "bench" / plot).stat().st_size > 1000


def test_parallel_benchmark_smoke_run():
    """bench_parallel.py (threads against worker processes) on small images: it runs, and every
    variant renders the same bits."""
    done = subprocess.run([sys.executable, str(RUN.with_name("bench_parallel.py")), "--quick", "--repeats", "1"],
                          capture_output=True, text=True, cwd=RUN.parents[2], timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    assert done.stdout.count("bit-identical to threads x1: True") == 2, done.stdout


def test_persistent_benchmark_standalone_run():
    """bench_persistent.py on its own (two frames of the bars, one run each way): it prints the section."""
    done = subprocess.run([sys.executable, str(RUN.with_name("bench_persistent.py")), "--repeats", "1", "--frames", "1-2",
                           "--no-heavy"], capture_output=True, text=True, cwd=RUN.parents[2], timeout=600)
    assert done.returncode == 0, done.stderr[-4000:]
    assert "## 11. Persistent data across frames" in done.stdout
    assert "- frames 2..N / frame 1 with persistent data, 11x11 bars (frames 1-2): <= 0.6, measured" in done.stdout

"""The benchmark suite in --smoke mode: it runs end to end and writes a report with finite numbers.

No timing assertions: the smoke sizes are too small to mean anything, this only keeps the
suite from rotting (the real report is ``tools/dev.sh tests/bench/run.py``).
"""

import json
import math
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
    for heading in ("## Goals", "## 1.", "## 2.", "## 3.", "## 4.", "## 5.", "## 6.", "## 7.", "## 8."):
        assert heading in text, heading
    assert "FAILED" not in text
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

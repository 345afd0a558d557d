"""glibc's malloc tuning (core/malloc.py): set by a render in its own process, a no-op elsewhere."""

import os
import subprocess
import sys
import textwrap

import pytest

from restframe_addon.core import malloc, workers

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.mark.skipif(not malloc.is_glibc(), reason="glibc's malloc only")
def test_a_render_on_threads_keeps_freed_large_arrays_for_the_next_allocation():
    """A fresh process renders a tiny image on a thread, then allocates twenty 3 MB arrays (a
    batch's temporaries, below numpy's huge-page size), frees them and allocates them again: with
    glibc's defaults the heap gives the freed 60 MB back to the system and the second round
    page-faults every page again; tuned, it reuses them."""
    script = textwrap.dedent(f"""
        import resource, sys
        sys.path[:0] = [{ROOT!r}, {os.path.join(ROOT, "tests", "core")!r}]
        import numpy as np
        from shapes import look_at_camera, quad
        from restframe_addon.core.prepared import prepare
        from restframe_addon.core.render import render_tiles
        from restframe_addon.core.scene import Mesh, RenderSettings, Scene
        v, t = quad((0.0, 5.0, 0.0), (4.0, 4.0), normal_axis=1)
        scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)), meshes=[Mesh("wall", v, t)])
        list(render_tiles(prepare(scene, RenderSettings(resolution=(8, 8), threads=1, parallelism="THREADS"))))
        size, count = 3 << 20, 20
        batch = lambda: [np.ones(size // 8) for _ in range(count)]
        batch()
        before = resource.getrusage(resource.RUSAGE_SELF).ru_minflt
        batch()
        print(resource.getrusage(resource.RUSAGE_SELF).ru_minflt - before, count * size // resource.getpagesize())
    """)
    environment = {k: v for k, v in os.environ.items() if k not in malloc.ENVIRONMENT}
    result = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300,
                            env=environment)
    assert result.returncode == 0, result.stdout + result.stderr
    faults, pages = map(int, result.stdout.split())
    assert faults < pages / 10


def test_off_glibc_nothing_is_changed(monkeypatch):
    def no_such_name(name):
        raise ValueError("unrecognized configuration name")

    monkeypatch.setattr(malloc, "_tuned", False)
    monkeypatch.setattr(malloc.os, "confstr", no_such_name)
    monkeypatch.setattr(malloc.ctypes, "CDLL", lambda *a: pytest.fail("looked for mallopt off glibc"))
    assert not malloc.is_glibc()
    assert malloc.tune() is False


def test_workers_start_with_the_same_tuning():
    assert workers.MALLOC_TUNING == {name: str(value) for name, _, value in malloc.TUNING}
    assert set(workers.WorkerPool()._environment.items()) >= set(malloc.ENVIRONMENT.items())

"""Ctrl-C (a real SIGINT) or SIGTERM reaching a worker's render child mid-frame: the child
writes and returns nothing, its task is retried, and the client writes only frames whose
result proves every tile was rendered."""

import os
import re
import shutil
import signal
import subprocess
import sys
import threading
import time

import pytest

from dask_helpers import ROOT, assert_same_exr, run_cli, start_cli
from restframe_addon import distributed


@pytest.fixture(scope="module")
def tiled_blend(tiny_blend, tmp_path_factory):
    """The tiny scene in 8-pixel tiles (12 of them): an interrupted render has delivered some
    tiles and not others, the partial image that must never be written."""
    path = tmp_path_factory.mktemp("tiled") / "tiled.blend"
    script = ("import sys, bpy, restframe_addon; restframe_addon.register(); "
              "bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False); "
              "bpy.context.scene.restframe.tile_size = 8; "
              "bpy.ops.wm.save_as_mainfile(filepath=sys.argv[2], copy=True)")
    made = subprocess.run([sys.executable, "-c", script, str(tiny_blend), str(path)], cwd=ROOT, capture_output=True,
                          text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    return path


def _render_child_reading(blend):
    """On a worker: the pid of its render child once it has opened ``blend`` (else None)."""
    from restframe_addon import distributed as on_worker

    server = on_worker._server
    if server is None or server.process.poll() is not None:
        return None
    return server.process.pid if any(str(blend) in line for line in list(server.log)) else None


def test_ctrl_c_on_a_render_child_retries_the_task_and_writes_only_complete_frames(tiled_blend, cluster, tmp_path):
    cluster_, client = cluster
    # 1024 samples: seconds a frame, so the signal lands after some tiles and before the last
    reference = tmp_path / "reference"
    result = run_cli(tiled_blend, "-o", reference / "f_#.exr", "--frames", "1-2", "--samples", "1024")
    assert result.returncode == 0, result.stderr
    # the signal goes a fraction of a frame's render into the frame: past the export, some
    # tiles in, most still to come (the cluster's two workers share the cores, so each is slower)
    delay = 0.5 * min(float(seconds) for seconds in re.findall(r"frame \d -> .* \((\d+\.\d+) s\)", result.stdout))
    out = tmp_path / "interrupted"
    job = start_cli(tiled_blend, "-o", out / "f_#.exr", "--frames", "1-2", "--samples", "1024",
                    "--scheduler", cluster_.scheduler_address)
    interrupted = {}

    def interrupt_a_rendering_child():
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and job.poll() is None:
            children = {worker: pid for worker, pid in client.run(_render_child_reading, str(tiled_blend)).items()
                        if pid is not None}
            if children:
                time.sleep(delay)
                worker, pid = sorted(children.items())[0]
                os.kill(pid, signal.SIGINT)
                interrupted.update(worker=worker, pid=pid)
                return
            time.sleep(0.05)

    watcher = threading.Thread(target=interrupt_a_rendering_child)
    watcher.start()
    stdout, stderr = job.communicate(timeout=240)
    watcher.join()
    assert interrupted, "no render child was rendering to be interrupted"
    assert job.returncode == 0, stderr
    for frame in (1, 2):  # each frame written once, and complete
        assert stdout.count(f"restframe: frame {frame} -> ") == 1, stdout
        assert_same_exr(out / f"f_{frame}.exr", reference / f"f_{frame}.exr")
    assert sorted(os.listdir(out)) == ["f_1.exr", "f_2.exr"]
    # the interrupted child left (its worker starts a new one for the next task)
    worker = interrupted["worker"]
    assert client.run(_render_child_reading, str(tiled_blend), workers=[worker])[worker] != interrupted["pid"]


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_an_interrupted_render_child_is_a_crash_to_retry_not_a_result(tiled_blend, tmp_path, signum):
    """render_task in this process: the child stops on the signal, says so and exits; the task
    raises TaskCrashed (Dask retries it) instead of returning bytes."""
    blend = tmp_path / "interrupt_me.blend"
    shutil.copy(tiled_blend, blend)
    # 65536 samples: tens of seconds to render whole (4096 came to 1.3 s once the renderer got faster),
    # so the signal below lands mid-render on any machine
    task = distributed.Task(blend=str(blend), copy="unused", scene="", frame=1, ext=".exr", samples=65536)
    box = {}

    def run():
        try:
            box["result"] = distributed.render_task(task)
        except Exception as error:
            box["error"] = error

    worker = threading.Thread(target=run)
    worker.start()
    deadline = time.monotonic() + 60
    while time.monotonic() < deadline and worker.is_alive():
        server = distributed._server
        if server is not None and any(str(blend) in line for line in list(server.log)):  # this test's child
            break
        time.sleep(0.02)
    time.sleep(1.0)  # past the export, into the tiles
    assert worker.is_alive(), box
    server.process.send_signal(signum)
    worker.join(timeout=60)
    assert isinstance(box.get("error"), distributed.TaskCrashed), box
    assert f"interrupted by {signal.Signals(signum).name}: frame 1 was not written" in str(box["error"])


def test_only_results_that_prove_every_tile_count_as_complete():
    assert distributed.is_complete({"data": b"x", "tiles": 6, "total": 6, "complete": True})
    for partial in ({"data": b"x"}, {"data": b"x", "tiles": 5, "total": 6, "complete": True},
                    {"data": b"x", "tiles": 0, "total": 0, "complete": True},
                    {"data": b"x", "tiles": 6, "total": 6, "complete": False}):
        assert not distributed.is_complete(partial), partial

"""The Dask render path: frame ranges and still regions on a LocalCluster of two worker
processes on loopback match single-process renders pixel for pixel; faults lose nothing."""

import contextlib
import glob
import os
import shutil
import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest

from dask_helpers import ROOT, assert_same_exr, exr_channels, png_pixels, run_cli, start_cli
from restframe_addon.distributed import DistributedError, Progress, Task, bundle_dir, render_task, split_regions
from restframe_addon.headless import write_bytes


# --------------------------------------------------------------------------- pure helpers
@pytest.mark.parametrize("size,count", [((32, 24), 4), ((32, 24), 1), ((33, 17), 6), ((7, 5), 35), ((1920, 1080), 16),
                                        ((5, 40), 3)])
def test_split_regions_tiles_the_image_exactly_once(size, count):
    width, height = size
    regions = split_regions(width, height, count)
    assert len(regions) == count
    cover = np.zeros((height, width), dtype=int)
    for x0, y0, x1, y1 in regions:
        assert 0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height
        cover[y0:y1, x0:x1] += 1
    assert (cover == 1).all()


def test_split_regions_refuses_impossible_splits():
    for args in [(4, 4, 0), (4, 4, 17), (3, 3, 7)]:
        with pytest.raises(DistributedError):
            split_regions(*args)


def test_progress_bar_counts_frames_rate_and_eta():
    class Stream:
        lines = []

        def write(self, text):
            self.lines.append(text)

        def flush(self):
            pass

    progress = Progress(total_tasks=8, total_frames=2, stream=Stream())
    progress.update(tasks=4, frames=1)
    line = Stream.lines[-1]
    assert "[###############...............] 1/2 frames (4/8 tasks)" in line
    assert "frames/s" in line and "ETA" in line
    progress.update(tasks=4, frames=1)
    assert "2/2 frames (8/8 tasks)" in Stream.lines[-1] and "ETA" not in Stream.lines[-1]


def test_region_option_parses_pixel_rectangles():
    from restframe_addon.__main__ import CommandError, parse_region

    assert parse_region("16,0,32,12") == (16, 0, 32, 12)
    assert parse_region(" 0, 1 ,2,3 ") == (0, 1, 2, 3)
    for bad in ("", "1,2,3", "1,2,3,4,5", "a,b,c,d", "-1,0,4,4"):
        with pytest.raises(CommandError):
            parse_region(bad)


def test_atomic_write_replaces_whole_files_only(tmp_path):
    target = tmp_path / "out" / "f.exr"
    write_bytes(str(target), b"one")
    write_bytes(str(target), b"two")
    assert target.read_bytes() == b"two"
    assert os.listdir(target.parent) == ["f.exr"]


@pytest.mark.parametrize("umask", [0o022, 0o077, 0o002])
def test_atomic_write_gives_the_mode_of_any_new_file(tmp_path, umask):
    """0666 less the umask, as open() would (a temporary file from mkstemp is 0600)."""
    previous = os.umask(umask)
    try:
        write_bytes(str(tmp_path / "f.exr"), b"data")
    finally:
        os.umask(previous)
    assert os.stat(tmp_path / "f.exr").st_mode & 0o777 == 0o666 & ~umask


# --------------------------------------------------------------------------- on the cluster
def test_frame_range_matches_single_process_and_reruns_skip(tiny_blend, reference, cluster, tmp_path):
    address = cluster[0].scheduler_address
    out = tmp_path / "dask"
    result = run_cli(tiny_blend, "-o", out / "f_#.exr", "--frames", "1-4", "--scheduler", address)
    assert result.returncode == 0, result.stderr
    assert "4 frame(s) x 1 region(s) on 2 Dask worker(s)" in result.stdout
    assert "4/4 frames (4/4 tasks)" in result.stdout and "frames/s" in result.stdout
    for frame in range(1, 5):
        assert_same_exr(out / f"f_{frame}.exr", reference / f"f_{frame}.exr")
    assert sorted(os.listdir(out)) == [f"f_{frame}.exr" for frame in range(1, 5)]  # no partial files
    umask = os.umask(0)
    os.umask(umask)
    assert {os.stat(out / f"f_{frame}.exr").st_mode & 0o777 for frame in range(1, 5)} == {0o666 & ~umask}

    # a rerun skips what is on disk and renders only the missing frame; --overwrite renders all
    stamps = {frame: os.stat(out / f"f_{frame}.exr").st_mtime_ns for frame in range(1, 5)}
    os.remove(out / "f_2.exr")
    result = run_cli(tiny_blend, "-o", out / "f_#.exr", "--frames", "1-4", "--scheduler", address)
    assert result.returncode == 0, result.stderr
    assert "skipping 3 frame(s) already on disk (1, 3, 4)" in result.stdout
    assert "1 frame(s) x 1 region(s)" in result.stdout and "frame 2 ->" in result.stdout
    assert_same_exr(out / "f_2.exr", reference / "f_2.exr")
    assert all(os.stat(out / f"f_{frame}.exr").st_mtime_ns == stamps[frame] for frame in (1, 3, 4))
    result = run_cli(tiny_blend, "-o", out / "f_#.exr", "--frames", "1,4", "--scheduler", address, "--overwrite")
    assert result.returncode == 0, result.stderr
    assert "skipping" not in result.stdout and "2 frame(s) x 1 region(s)" in result.stdout
    assert os.stat(out / "f_1.exr").st_mtime_ns != stamps[1]
    assert_same_exr(out / "f_4.exr", reference / "f_4.exr")


def test_still_in_four_regions_matches_single_process(tiny_blend, reference, cluster, tmp_path):
    address = cluster[0].scheduler_address
    result = run_cli(tiny_blend, "-o", tmp_path / "still.exr", "--frame", "3", "--regions", "4", "--scheduler", address)
    assert result.returncode == 0, result.stderr
    assert "1 frame(s) x 4 region(s)" in result.stdout and "1/1 frames (4/4 tasks)" in result.stdout
    assert_same_exr(tmp_path / "still.exr", reference / "f_3.exr")
    # the regions really were rendered apart: a region alone is a cropped part of the image
    result = run_cli(tiny_blend, "-o", tmp_path / "part.exr", "--frame", "3", "--region", "16,0,32,12")
    assert result.returncode == 0, result.stderr
    part, whole = exr_channels(tmp_path / "part.exr"), exr_channels(reference / "f_3.exr")
    for name, pixels in part.items():
        assert pixels.shape == (12, 16)
        np.testing.assert_allclose(pixels, whole[name][12:24, 16:32], rtol=0, atol=1e-6)  # EXR rows: top first

    # an 8-bit image goes through Blender's colour management once assembled: the same bytes
    result = run_cli(tiny_blend, "-o", tmp_path / "still.png", "--frame", "3", "--regions", "4", "--scheduler", address)
    assert result.returncode == 0, result.stderr
    got, want = png_pixels(tmp_path / "still.png"), png_pixels(reference / "still.png")
    assert got.shape == want.shape == (24, 32, 3) and want.std() > 5
    assert np.array_equal(got, want)
    assert sorted(os.listdir(tmp_path)) == ["part.exr", "still.exr", "still.png"]


def test_still_regions_on_a_local_cluster_started_by_the_command(tiny_blend, reference, tmp_path):
    """Without --scheduler the command starts its own LocalCluster (--workers processes)."""
    result = run_cli(tiny_blend, "-o", tmp_path / "s.exr", "--frame", "3", "--regions", "2", "--workers", "2")
    assert result.returncode == 0, result.stderr
    assert "1 frame(s) x 2 region(s) on 2 Dask worker(s) at tcp://127.0.0.1:" in result.stdout
    assert_same_exr(tmp_path / "s.exr", reference / "f_3.exr")


def _suspicious(keys, dask_scheduler=None):
    """On the scheduler: how often each task was on a worker that died while running it."""
    return {key: dask_scheduler.tasks[key].suspicious for key in keys if key in dask_scheduler.tasks}


def test_killed_worker_loses_no_frame(tiny_blend, cluster, tmp_path):
    cluster_, client = cluster
    # 512 samples: long enough per frame that a kill lands mid-frame (a frame that ends first is no test:
    # the killer then tries the next busy worker)
    reference = tmp_path / "reference"
    result = run_cli(tiny_blend, "-o", reference / "f_#.exr", "--frames", "1-4", "--samples", "512")
    assert result.returncode == 0, result.stderr
    out = tmp_path / "killed"
    job = start_cli(tiny_blend, "-o", out / "f_#.exr", "--frames", "1-4", "--samples", "512",
                    "--scheduler", cluster_.scheduler_address)
    killed = {}

    def kill_a_busy_worker():
        deadline = time.monotonic() + 90
        while time.monotonic() < deadline and job.poll() is None:
            busy = {worker: [str(key) for key in keys] for worker, keys in client.processing().items()
                    if any(str(key).startswith("restframe-frame") for key in keys)}
            if not busy:
                time.sleep(0.02)
                continue
            worker = sorted(busy)[0]
            time.sleep(0.2)  # the render has started
            pid = client.run(os.getpid, workers=[worker])[worker]
            os.kill(pid, signal.SIGKILL)
            killed.update(worker=worker, pid=pid, keys=busy[worker])
            end = time.monotonic() + 10
            while time.monotonic() < end:  # the scheduler notices the death and reschedules
                counts = client.run_on_scheduler(_suspicious, busy[worker])
                if any(counts.values()):
                    killed["suspicious"] = counts
                    return
                time.sleep(0.05)
            client.wait_for_workers(2, timeout=60)  # its frame had ended first: wait for the nanny, try again

    killer = threading.Thread(target=kill_a_busy_worker)
    killer.start()
    stdout, stderr = job.communicate(timeout=180)
    killer.join()
    assert job.returncode == 0, stderr
    assert killed, "no worker was busy to be killed"
    assert killed.get("suspicious"), f"the killed worker had no running task: {killed}"
    for frame in range(1, 5):  # every frame, each exactly once and complete
        assert stdout.count(f"restframe: frame {frame} -> ") == 1, stdout
        assert_same_exr(out / f"f_{frame}.exr", reference / f"f_{frame}.exr")
    assert sorted(os.listdir(out)) == [f"f_{frame}.exr" for frame in range(1, 5)]
    client.wait_for_workers(2, timeout=60)  # the nanny brought the worker back for later tests


def test_shipped_blend_renders_where_the_path_is_not_visible(tiny_blend, reference, tmp_path):
    """A worker that cannot see the client's path renders from the bytes the client shipped."""
    task = Task(blend="/nonexistent/client/only/tiny.blend", copy="test-" + os.urandom(6).hex(), scene="",
                frame=2, ext=".exr")
    try:
        result = render_task(task, {"tiny.blend": tiny_blend.read_bytes()})
    finally:
        shutil.rmtree(bundle_dir(task.copy), ignore_errors=True)
    assert "error" not in result, result
    (tmp_path / "shipped.exr").write_bytes(result["data"])
    assert_same_exr(tmp_path / "shipped.exr", reference / "f_2.exr")
    # not shipped and not visible: the worker's error names the file (and is not retried)
    result = render_task(task, None)
    assert "no such .blend file" in result["error"] and "/nonexistent/client/only/tiny.blend" in result["error"]


@contextlib.contextmanager
def outside_worker(command, cwd, env):
    """A Dask worker process started by ``command`` (not by the cluster), stopped on leaving."""
    worker = subprocess.Popen(command, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        yield worker
    finally:
        worker.terminate()
        worker.wait(timeout=30)


def test_worker_that_cannot_import_the_addon_is_a_clear_error(tiny_blend, tmp_path):
    from dask.distributed import LocalCluster

    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=":0", processes=True) as empty:
        env = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
        with outside_worker([sys.executable, "-m", "distributed.cli.dask_worker", empty.scheduler_address,
                             "--nthreads", "1", "--no-dashboard"], tmp_path, env):
            result = run_cli(tiny_blend, "-o", tmp_path / "x.exr", "--frame", "1", "--scheduler",
                             empty.scheduler_address)
    assert result.returncode == 1
    assert "1 of 1 Dask worker(s) cannot import the RESTframe add-on" in result.stderr
    assert "No module named 'restframe_addon'" in result.stderr
    assert "Traceback" not in result.stderr
    assert not (tmp_path / "x.exr").exists()


def test_render_errors_on_workers_reach_the_client(tmp_path, cluster):
    """A scene error is reported once per frame with its message (not retried), exit status 1."""
    script = ("import sys, bpy, restframe_addon; restframe_addon.register(); "
              "bpy.ops.wm.read_factory_settings(use_empty=True); s = bpy.context.scene; "
              "cam = bpy.data.objects.new('Camera', bpy.data.cameras.new('Camera')); s.collection.objects.link(cam); "
              "s.camera = cam; s.render.resolution_x, s.render.resolution_y = 8, 6; "
              "bpy.ops.mesh.primitive_plane_add(); bpy.context.object.name = 'Tachyon'; "
              "bpy.context.object.restframe.velocity = (0, 0, 1.5); "
              "bpy.ops.wm.save_as_mainfile(filepath=sys.argv[1], copy=True)")
    blend = tmp_path / "tachyon.blend"
    made = subprocess.run([sys.executable, "-c", script, str(blend)], cwd=ROOT, capture_output=True, text=True,
                          timeout=120)
    assert made.returncode == 0, made.stderr
    result = run_cli(blend, "-o", tmp_path / "t_#.png", "--frames", "1-2", "--scheduler", cluster[0].scheduler_address)
    assert result.returncode == 1
    for frame in (1, 2):
        assert result.stderr.count(f"restframe: error: frame {frame}: Error: RESTframe: Tachyon: speed 1.5 c is "
                                   "not below the speed of light") == 1, result.stderr
    assert "2 frame(s) failed" in result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["tachyon.blend"]


# The tiny scene with a plane in front of the camera linked from lib.blend beside it (relative path).
MAKE_LINKED = """
import sys, bpy, mathutils, restframe_addon
restframe_addon.register()
tiny, folder = sys.argv[1], sys.argv[2]
bpy.ops.wm.open_mainfile(filepath=tiny, load_ui=False)
camera = bpy.context.scene.camera.matrix_world.copy()
bpy.ops.wm.read_factory_settings(use_empty=True)
mesh = bpy.data.meshes.new("LinkedPlane")
mesh.from_pydata([(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.5, 0.5, 0), (-0.5, 0.5, 0)], [], [(0, 1, 2, 3)])
plane = bpy.data.objects.new("LinkedPlane", mesh)
bpy.context.scene.collection.objects.link(plane)
plane.matrix_world = camera @ mathutils.Matrix.Translation((0.3, 0.0, -3.0))
bpy.ops.wm.save_as_mainfile(filepath=folder + "/lib.blend")
bpy.ops.wm.open_mainfile(filepath=tiny, load_ui=False)
bpy.ops.wm.save_as_mainfile(filepath=folder + "/linked.blend", copy=False)
with bpy.data.libraries.load(folder + "/lib.blend", link=True, relative=True) as (source, linked):
    linked.objects = ["LinkedPlane"]
for plane in linked.objects:
    bpy.context.scene.collection.objects.link(plane)
bpy.ops.wm.save_mainfile()
"""


@pytest.fixture(scope="module")
def linked_blend(tiny_blend, tmp_path_factory):
    folder = tmp_path_factory.mktemp("linked")
    made = subprocess.run([sys.executable, "-c", MAKE_LINKED, str(tiny_blend), str(folder)], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    return folder / "linked.blend"


def test_blend_is_shipped_to_a_worker_that_cannot_see_it(tiny_blend, linked_blend, reference, tmp_path):
    """A worker in its own mount namespace, with empty tmpfs over the .blends' folders, gets each
    .blend from the client, with the library it links, and renders the same pixels."""
    from dask.distributed import LocalCluster

    folders = [os.path.dirname(tiny_blend), os.path.dirname(linked_blend)]
    hide = " && ".join(f"mount -t tmpfs none '{folder}'" for folder in folders)
    probe = subprocess.run(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                            f"{hide} && test ! -e '{tiny_blend}'"], capture_output=True)
    if probe.returncode != 0:
        pytest.skip(f"no private mount namespace here: {probe.stderr.decode().strip()}")
    linked_reference = tmp_path / "linked_reference.exr"
    result = run_cli(linked_blend, "-o", linked_reference, "--frame", "2")
    assert result.returncode == 0, result.stderr
    combined = "ViewLayer.Combined/ViewLayer.Combined.R"
    assert not np.array_equal(exr_channels(linked_reference)[combined], exr_channels(reference / "f_2.exr")[combined])
    with LocalCluster(n_workers=0, host="127.0.0.1", dashboard_address=":0", processes=True) as empty:
        with outside_worker(["unshare", "--mount", "--propagation", "private", "sh", "-c",
                             f"{hide} && exec '{sys.executable}' -m distributed.cli.dask_worker "
                             f"{empty.scheduler_address} --nthreads 1 --no-dashboard"],
                            tmp_path, dict(os.environ, PYTHONPATH=ROOT)):
            result = run_cli(tiny_blend, "-o", tmp_path / "f_#.exr", "--frames", "2", "--scheduler",
                             empty.scheduler_address)
            linked = run_cli(linked_blend, "-o", tmp_path / "linked.exr", "--frame", "2", "--scheduler",
                             empty.scheduler_address)
    from restframe_addon.distributed import file_digest

    copies = [copy for blend in (tiny_blend, linked_blend) for copy in glob.glob(bundle_dir(file_digest(str(blend))) + "*")]
    for copy in copies:
        shutil.rmtree(copy, ignore_errors=True)
    assert result.returncode == 0, result.stderr
    assert "(the .blend is shipped to the workers)" in result.stdout
    assert_same_exr(tmp_path / "f_2.exr", reference / "f_2.exr")
    assert linked.returncode == 0, linked.stderr
    assert_same_exr(tmp_path / "linked.exr", linked_reference)  # the linked plane is there
    assert not copies, "the worker kept its shipped copy of the .blend after the job"


def test_shipped_copies_unused_for_a_day_are_removed(tmp_path, monkeypatch):
    """A copy whose job never ended cleanly (client interrupted) goes when a render server starts."""
    from restframe_addon import distributed

    monkeypatch.setattr(distributed, "_task_dir_root", lambda: str(tmp_path))
    for name, age in (("old", distributed.STALE_COPY_SECONDS + 60), ("recent", 60)):
        os.makedirs(os.path.join(bundle_dir(name), "files"))
        marker = os.path.join(bundle_dir(name), ".complete")
        open(marker, "w").close()
        os.utime(marker, (time.time() - age, time.time() - age))
    distributed._remove_stale_copies()
    assert sorted(os.listdir(os.path.join(tmp_path, "blends"))) == ["recent"]


MAKE_BORDER = """
import sys, bpy, restframe_addon
restframe_addon.register()
bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False)
render = bpy.context.scene.render
render.use_border, render.use_crop_to_border = True, sys.argv[3] == "crop"
render.border_min_x, render.border_max_x, render.border_min_y, render.border_max_y = 0.2, 0.7, 0.15, 0.9
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[2], copy=True)
"""


@pytest.mark.parametrize("crop", ["crop", "no-crop"])
def test_regions_fill_the_files_render_border_as_one_render_does(tiny_blend, cluster, tmp_path, crop):
    blend = tmp_path / "border.blend"
    made = subprocess.run([sys.executable, "-c", MAKE_BORDER, str(tiny_blend), str(blend), crop], cwd=ROOT,
                          capture_output=True, text=True, timeout=120)
    assert made.returncode == 0, made.stderr
    result = run_cli(blend, "-o", tmp_path / "whole.exr", "--frame", "3")
    assert result.returncode == 0, result.stderr
    result = run_cli(blend, "-o", tmp_path / "regions.exr", "--frame", "3", "--regions", "4", "--scheduler",
                     cluster[0].scheduler_address)
    assert result.returncode == 0, result.stderr
    shape = (18, 16) if crop == "crop" else (24, 32)  # the border: x 6..22, y 3..21 (Blender truncates)
    assert exr_channels(tmp_path / "whole.exr")["ViewLayer.Combined/ViewLayer.Combined.R"].shape == shape
    assert_same_exr(tmp_path / "regions.exr", tmp_path / "whole.exr")


def test_a_render_child_runs_as_many_tile_workers_as_its_dask_worker_has_threads(tiny_blend, cluster):
    """The cluster's workers have one thread each: a child starting a tile worker per core of the
    machine would run cores x cores render processes."""
    from restframe_addon import distributed

    client = cluster[1]
    task = distributed.Task(blend=str(tiny_blend), copy="unused", scene="", frame=1, ext=".png")
    result = client.submit(distributed.render_task, task, pure=False).result(timeout=240)
    assert distributed.is_complete(result) and result["tile_workers"] == 1
    assert distributed.dask_cores() is None  # not in a Dask worker

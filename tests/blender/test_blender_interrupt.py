"""Interrupted renders write nothing as complete: Ctrl-C (a real SIGINT) and SIGTERM sent to a
headless render, Ctrl-C in a script that calls the render operator, and a cancelled render
that Blender saves as an EXR."""

import os
import signal
import subprocess
import sys
import textwrap
import time

import bpy
import pytest

from blender_helpers import add_camera, add_plane, add_sun
from restframe_addon import engine

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))


@pytest.fixture(scope="module")
def slow_blend(tmp_path_factory):
    """A lit plane at 128x96 with 4096 samples: several seconds a frame even on a fast core, so a
    signal sent 1.5 s in lands mid-frame."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 128, 96, 100
    scene.restframe.samples = 4096
    add_camera(scene)
    add_plane(scene, velocity=(0.5, 0.0, 0.0))
    add_sun(scene)
    path = tmp_path_factory.mktemp("slow") / "slow.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(path), copy=True)
    return path


def start_cli(*args):
    return subprocess.Popen([sys.executable, "-m", "restframe_addon", "render", *map(str, args)], cwd=ROOT,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)


def wait_for_line(stream, start: str) -> list[str]:
    lines = []
    for line in stream:
        lines.append(line)
        if line.startswith(start):
            return lines
    raise AssertionError(f"no line starting {start!r} in {lines}")


@pytest.mark.parametrize("signum", [signal.SIGINT, signal.SIGTERM], ids=["SIGINT", "SIGTERM"])
def test_a_signal_mid_frame_stops_the_range_and_writes_nothing_for_that_frame(slow_blend, tmp_path, signum):
    out = tmp_path / "f_#.png"
    job = start_cli(slow_blend, "-o", out, "--frames", "1-3")
    try:
        wait_for_line(job.stdout, "restframe: frame 1 -> ")
        # frame 2 is rendering now (a few seconds of it): stop the command
        time.sleep(0.5)
        job.send_signal(signum)
        stdout, stderr = job.communicate(timeout=120)
    finally:
        job.kill()
        job.wait()
    assert job.returncode == 128 + signum, (stdout, stderr)
    assert f"interrupted by {signal.Signals(signum).name}: frame 2 was not written" in stderr
    assert "Traceback" not in stderr
    assert "frame 2 ->" not in stdout and "frame 3 ->" not in stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_1.png"]  # no frame 2, 3 or partial file

    # a rerun renders the frames that are missing
    rerun = subprocess.run([sys.executable, "-m", "restframe_addon", "render", str(slow_blend), "-o", str(out),
                            "--frames", "2-3", "--samples", "1"], cwd=ROOT, capture_output=True, text=True,
                           timeout=120)
    assert rerun.returncode == 0, rerun.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["f_1.png", "f_2.png", "f_3.png"]


def test_ctrl_c_in_a_script_makes_the_render_operator_fail(slow_blend, tmp_path):
    """A script with Python's own Ctrl-C handling (KeyboardInterrupt) must not get a partial
    image back as if the render had finished: the operator raises instead."""
    script = textwrap.dedent(f"""
        import os, sys, bpy, restframe_addon
        restframe_addon.register()
        bpy.ops.wm.open_mainfile(filepath={str(slow_blend)!r}, load_ui=False)
        print("rendering", flush=True)
        try:
            bpy.ops.render.render()
            print("finished", flush=True)
            status = 0
        except RuntimeError as error:
            print("operator failed:", error, flush=True)
            status = 3
        sys.stderr.flush()
        os._exit(status)  # bpy 4.2 crashes in its exit handlers once the add-on registered (conftest.py)
    """)
    child = subprocess.Popen([sys.executable, "-c", script], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                             text=True)
    try:
        wait_for_line(child.stdout, "rendering")
        time.sleep(1.5)  # past the export, into the tiles
        child.send_signal(signal.SIGINT)
        stdout, stderr = child.communicate(timeout=120)
    finally:
        child.kill()
        child.wait()
    assert "finished" not in stdout, stderr
    assert "operator failed:" in stdout and "render interrupted" in stdout, (stdout, stderr)
    assert child.returncode == 3


def test_ctrl_c_in_the_pass_list_callback_makes_the_next_render_fail(slow_blend):
    """A Ctrl-C landing in ``update_render_passes`` (Blender calls it just before render and prints
    and drops its exceptions) must not let the render finish as if nothing happened; the render
    after that one is not affected."""
    script = textwrap.dedent(f"""
        import os, sys, bpy, restframe_addon
        from restframe_addon import engine
        restframe_addon.register()
        bpy.ops.wm.open_mainfile(filepath={str(slow_blend)!r}, load_ui=False)
        bpy.context.scene.restframe.samples = 1
        listed = engine.list_render_passes
        calls = []
        def interrupted_once(*args):
            calls.append(1)
            if len(calls) == 1:
                raise KeyboardInterrupt  # as a SIGINT arriving during the callback
            return listed(*args)
        engine.list_render_passes = interrupted_once
        for attempt in ("first", "second"):
            try:
                bpy.ops.render.render()
                print(attempt, "finished", flush=True)
            except RuntimeError as error:
                print(attempt, "failed:", error, flush=True)
        sys.stderr.flush()
        os._exit(0)  # bpy 4.2 crashes in its exit handlers once the add-on registered (conftest.py)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr[-2000:]
    assert "first failed:" in result.stdout and "render interrupted" in result.stdout, (result.stdout, result.stderr)
    assert "second finished" in result.stdout, (result.stdout, result.stderr)


def test_a_cancelled_render_still_saves_as_an_exr_without_crashing(slow_blend, tmp_path):
    """Blender 5.0 segfaulted writing the EXR of a render that stopped before its first tile
    (no result handed over); the cancelled render is reported as incomplete."""
    script = textwrap.dedent(f"""
        import os, sys, bpy, restframe_addon
        from restframe_addon import engine
        restframe_addon.register()
        bpy.ops.wm.open_mainfile(filepath={str(slow_blend)!r}, load_ui=False)
        scene = bpy.context.scene
        if hasattr(scene.render.image_settings, "media_type"):  # Blender 5.0
            scene.render.image_settings.media_type = 'MULTI_LAYER_IMAGE'
        else:
            scene.render.image_settings.file_format = 'OPEN_EXR_MULTILAYER'
        scene.render.filepath = {str(tmp_path / "cancelled.exr")!r}
        engine.RestframeRenderEngine.should_stop = lambda self: True  # Esc before anything was rendered
        bpy.ops.render.render(write_still=True)
        outcome = engine.take_outcome() if hasattr(engine, "take_outcome") else None
        print("outcome", outcome is not None and outcome.complete, flush=True)
        sys.stderr.flush()
        os._exit(0)  # bpy 4.2 crashes in its exit handlers once the add-on registered (conftest.py)
    """)
    result = subprocess.run([sys.executable, "-c", script], cwd=ROOT, capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, (result.returncode, result.stderr[-2000:])
    assert "outcome False" in result.stdout
    assert (tmp_path / "cancelled.exr").exists()


def test_the_outcome_of_a_render_counts_its_tiles(scene):
    add_camera(scene)
    add_plane(scene)
    scene.restframe.tile_size = 8  # 21x15 pixels: 3x2 tiles
    engine.take_outcome()
    bpy.ops.render.render()
    outcome = engine.take_outcome()
    assert outcome.complete and outcome.tiles == outcome.total == 6
    assert engine.take_outcome() is None  # taken once

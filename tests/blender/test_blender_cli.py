"""Headless rendering: python -m restframe_addon render FILE.blend -o OUT (bpy as a module)."""

import hashlib
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, read_exr
from restframe_addon.__main__ import CommandError, output_path, parse_frames

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
SAMPLE = os.path.join(ROOT, "sample_blends", "moving_sphere.blend")


@pytest.fixture(scope="module")
def sample(tmp_path_factory):
    """The sample .blend; older Blenders cannot read the committed 5.0 file, so they build their own."""
    if bpy.app.version >= (5, 0, 0):
        return SAMPLE
    out = tmp_path_factory.mktemp("samples")
    code = ("import os, sys; sys.path[:0] = [{samples!r}, {root!r}]; import make_samples, restframe_addon; "
            "make_samples.HERE = {out!r}; restframe_addon.register(); make_samples.build_moving_sphere(); "
            "sys.stdout.flush(); os._exit(0)")
    subprocess.run([sys.executable, "-c", code.format(samples=os.path.dirname(SAMPLE), root=ROOT, out=str(out))],
                   cwd=ROOT, capture_output=True, timeout=300, check=True)
    return str(out / "moving_sphere.blend")


def run_cli(*args):
    return subprocess.run([sys.executable, "-m", "restframe_addon", "render", *map(str, args)],
                          cwd=ROOT, capture_output=True, text=True, timeout=300)


def digest(path):
    with open(path, "rb") as fh:
        return hashlib.sha256(fh.read()).hexdigest()


def test_parse_frames():
    assert parse_frames("7") == [7]
    assert parse_frames("1-4") == [1, 2, 3, 4]
    assert parse_frames("1-9:4,20,3..4") == [1, 5, 9, 20, 3, 4]
    assert parse_frames("-2-0") == [-2, -1, 0]
    for bad in ("", "a", "5-1", "1-4:0"):
        with pytest.raises(CommandError):
            parse_frames(bad)


def test_output_path():
    assert output_path("out/a.png", 3, several=False) == "out/a.png"
    assert output_path("out/a.png", 3, several=True) == "out/a_0003.png"
    assert output_path("out/f_###.exr", 12, several=True) == "out/f_012.exr"
    assert output_path("o#/f_#.exr", 12, several=False) == "o#/f_12.exr"  # only the file name


def test_render_a_still_png_and_leave_the_blend_untouched(tmp_path, sample):
    before = digest(sample)
    files = sorted(os.listdir(os.path.dirname(sample)))
    out = tmp_path / "still.png"
    result = run_cli(sample, "-o", out, "--frame", "1", "--percentage", "10", "--samples", "1")
    assert result.returncode == 0, result.stderr
    assert f"frame 1 -> {out}" in result.stdout
    image = bpy.data.images.load(str(out))
    assert tuple(image.size) == (32, 18)
    pixels = np.array(image.pixels[:]).reshape(18, 32, 4)
    assert pixels[..., :3].std() > 0.01  # a picture, not a blank frame
    assert digest(sample) == before
    assert sorted(os.listdir(os.path.dirname(sample))) == files  # no backup (.blend1) or other file
    assert [p.name for p in tmp_path.iterdir()] == ["still.png"]  # no partial files left


def test_render_a_frame_range_to_multilayer_exr(tmp_path, sample):
    result = run_cli(sample, "-o", tmp_path / "f_##.exr", "--frames", "1-2", "--percentage", "5", "--samples", "1")
    assert result.returncode == 0, result.stderr
    first, second = read_exr(tmp_path / "f_01.exr"), read_exr(tmp_path / "f_02.exr")
    assert {"Combined", "Doppler", "Emission Time"} <= set(first)
    assert first["Doppler"].shape == (9, 16, 1)
    # the static floor (D = 1) is seen exactly one frame (1/24 s) later in the next frame
    floor = (first["Doppler"][..., 0] == 1.0) & (second["Doppler"][..., 0] == 1.0)
    assert floor.sum() > 20
    later = second["Emission Time"][..., 0][floor] - first["Emission Time"][..., 0][floor]
    np.testing.assert_allclose(later, 1.0 / 24.0, atol=1e-5)
    # the approaching sphere is blue-shifted somewhere
    assert first["Doppler"].max() > 1.2


def test_render_errors_exit_non_zero_with_the_message(scene, tmp_path):
    add_camera(scene)
    add_plane(scene, "Tachyon", velocity=(0.0, 0.0, 1.5))
    blend = tmp_path / "bad.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    result = run_cli(blend, "-o", tmp_path / "bad.png")
    assert result.returncode == 1
    assert "Tachyon: speed 1.5 c is not below the speed of light" in result.stderr
    assert not (tmp_path / "bad.png").exists()

    result = run_cli(tmp_path / "missing.blend", "-o", tmp_path / "x.png")
    assert result.returncode == 1 and "no such .blend file" in result.stderr
    result = run_cli(blend, "-o", tmp_path / "x.gif")
    assert result.returncode == 1 and "unknown output extension" in result.stderr


def test_unreadable_files_and_unwritable_outputs_are_clear_errors_before_rendering(sample, tmp_path):
    text = tmp_path / "notes.blend"
    text.write_text("not a .blend file\n")
    truncated = tmp_path / "truncated.blend"
    truncated.write_bytes(open(sample, "rb").read()[:30000])
    folder = tmp_path / "taken.png"
    folder.mkdir()
    plain_file = tmp_path / "plain"
    plain_file.write_text("")
    cases = [
        ((text, "-o", tmp_path / "x.png"), f"{text}: not a readable .blend file"),
        ((truncated, "-o", tmp_path / "x.png"), f"{truncated}: not a readable .blend file"),
        ((sample, "-o", folder), f"{folder}: is a folder, not an image file name"),
        ((sample, "-o", plain_file / "x.png"), f"{plain_file} is a file, not a folder"),
        ((sample, "-o", "/proc/restframe.png"), "/proc/restframe.png: cannot write in /proc"),
        # the Dask path checks its outputs before it looks for a scheduler
        ((sample, "-o", plain_file / "f_#.exr", "--frames", "1-2", "--scheduler", "tcp://127.0.0.1:9"),
         f"{plain_file} is a file, not a folder"),
        ((sample, "-o", tmp_path / "x.png", "--scheduler", "nonsense"),
         "--scheduler 'nonsense' is not a Dask scheduler address"),
    ]
    for args, message in cases:
        result = run_cli(*args, "--percentage", "5", "--samples", "1")
        assert result.returncode == 1, (args, result.stderr)
        assert result.stderr.count("restframe: error: ") == 1 and message in result.stderr, (args, result.stderr)
        assert "Traceback" not in result.stderr, result.stderr
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.blend", "plain", "taken.png", "truncated.blend"]
    assert not os.listdir(folder)


@pytest.mark.parametrize("args,message", [
    (("--frames", "1-1000000000"), "frame 1000000000 is beyond Blender's limit of 1048574"),
    (("--frames=-1048575-0",), "frame -1048575 is beyond Blender's limit"),
    (("--frame", "1048575"), "frame 1048575 is beyond Blender's limit"),
])
def test_frames_beyond_blenders_limit_are_refused(sample, tmp_path, args, message):
    """frame_set clamps to 1048574: a frame beyond would render that frame under its own name."""
    result = run_cli(sample, "-o", tmp_path / "f_#.png", *args)
    assert result.returncode == 1 and f"restframe: error: {message}" in result.stderr, result.stderr
    assert not os.listdir(tmp_path)


@pytest.mark.parametrize("args", [("--workers", "0"), ("--workers", "-1"), ("--regions", "0"), ("--regions", "-4"),
                                  ("--retries", "-1")])
def test_impossible_dask_counts_are_refused(sample, tmp_path, args):
    result = run_cli(sample, "-o", tmp_path / "x.png", *args)
    assert result.returncode == 2 and f"argument {args[0]}: must be at least" in result.stderr, result.stderr
    assert not os.listdir(tmp_path)


def test_pixel_aspect_with_a_multilayer_exr_is_a_clear_error(scene, tmp_path):
    """Blender 5.0's multilayer EXR writer fails on a pixel aspect other than 1 (for Cycles too)."""
    add_camera(scene)
    add_plane(scene)
    scene.render.pixel_aspect_x = 2.0
    blend = tmp_path / "aspect.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    result = run_cli(blend, "-o", tmp_path / "wide.exr")
    if bpy.app.version >= (5, 0, 0):
        assert result.returncode == 1, result.stderr
        assert "cannot write a multilayer EXR with a pixel aspect of 2:1" in result.stderr
        assert "Traceback" not in result.stderr and not (tmp_path / "wide.exr").exists()
    else:
        assert result.returncode == 0, result.stderr
    result = run_cli(blend, "-o", tmp_path / "wide.png")
    assert result.returncode == 0, result.stderr

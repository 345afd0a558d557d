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

"""Fixtures for the Dask tests: a tiny .blend, single-process references and a LocalCluster
of two worker processes on loopback."""

import logging
import subprocess
import sys

import pytest

from dask_helpers import ROOT, SAMPLE, run_cli

# The sample's moving sphere at 32x24, 2 samples, no dithering (8-bit images exact), saved as
# a copy.  Run in a child so this test process never imports bpy.
MAKE_TINY = """
import sys
import bpy
import restframe_addon
restframe_addon.register()
bpy.ops.wm.open_mainfile(filepath=sys.argv[1], load_ui=False)
scene = bpy.context.scene
scene.render.resolution_x, scene.render.resolution_y, scene.render.resolution_percentage = 32, 24, 100
scene.render.dither_intensity = 0.0
scene.restframe.samples = 2
bpy.ops.wm.save_as_mainfile(filepath=sys.argv[2], copy=True)
"""


@pytest.fixture(scope="session")
def tiny_blend(tmp_path_factory):
    path = tmp_path_factory.mktemp("blend") / "tiny.blend"
    result = subprocess.run([sys.executable, "-c", MAKE_TINY, SAMPLE, str(path)], cwd=ROOT,
                            capture_output=True, text=True, timeout=120)
    assert result.returncode == 0, result.stderr
    return path


@pytest.fixture(scope="session")
def reference(tiny_blend, tmp_path_factory):
    """Single-process renders (no Dask) of frames 1-4 as multilayer EXR and frame 3 as PNG."""
    folder = tmp_path_factory.mktemp("reference")
    result = run_cli(tiny_blend, "-o", folder / "f_#.exr", "--frames", "1-4")
    assert result.returncode == 0, result.stderr
    result = run_cli(tiny_blend, "-o", folder / "still.png", "--frame", "3")
    assert result.returncode == 0, result.stderr
    return folder


@pytest.fixture(scope="session")
def cluster():
    """A LocalCluster of two single-threaded worker processes on 127.0.0.1 (with nannies, so a
    killed worker comes back)."""
    from dask.distributed import Client, LocalCluster

    cluster = LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                           dashboard_address=":0", silence_logs=logging.ERROR)
    client = Client(cluster)
    yield cluster, client
    client.close()
    cluster.close()

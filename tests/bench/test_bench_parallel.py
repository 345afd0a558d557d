"""The arithmetic the benchmark report's sections 10 and 11 rest on: Amdahl's projection, the tiles
and shares a render on N workers gets, and the heavy sphere's triangle count."""

import pytest
from bench_common import ball_scene, settings
from bench_parallel import amdahl, tiles_and_shares
from bench_persistent import HEAVY_SEGMENTS, sphere_triangles

from restframe_addon.core.prepared import prepare


@pytest.mark.parametrize("serial, work, cores", [(0.0, 5.0, 16), (1.0, 9.0, 16), (0.02, 3.1, 8), (4.0, 1.0, 2)])
def test_amdahl_is_the_speed_up_of_a_serial_share(serial, work, cores):
    share = serial / (serial + work)
    assert amdahl(serial, work, cores) == pytest.approx(1.0 / (share + (1.0 - share) / cores), rel=1e-12)


def test_amdahl_limits():
    assert amdahl(0.0, 2.0, 16) == pytest.approx(16.0)  # no serial work: every core counts
    assert amdahl(3.0, 0.0, 16) == pytest.approx(1.0)  # nothing to share out
    assert amdahl(0.5, 2.0, 1) == pytest.approx(1.0)


def test_tiles_and_shares_are_those_of_a_render_on_that_many_workers():
    """512x256 at 256-px tiles is 2 tiles on one worker.  For 8 workers the tiles are halved,
    height first, to 8 of 128x128 (16384 px); each is cut into 2 bands, since a band is about
    1/32 of the pixels left but at least 8192.  For 16: 16 tiles of 128x64, one share each."""
    prepared = prepare(ball_scene(), settings((512, 256), tile_size=256, threads=1))
    assert len(prepared.tiles()) == 2
    assert tiles_and_shares(prepared, 1) == (2, 2)
    assert tiles_and_shares(prepared, 8) == (8, 16)
    assert tiles_and_shares(prepared, 16) == (16, 16)


def test_the_heavy_sphere_is_the_issues_261k_triangles():
    assert sphere_triangles(HEAVY_SEGMENTS) == 261_120


@pytest.mark.parametrize("segments", [8, 32, 64])
def test_sphere_triangles_counts_blenders_uv_sphere(segments):
    bpy = pytest.importorskip("bpy")
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=segments, ring_count=segments // 2)
    mesh = bpy.context.active_object.data
    mesh.calc_loop_triangles()
    assert sphere_triangles(segments) == len(mesh.loop_triangles)

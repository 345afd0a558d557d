"""Persistent data across frames (issue 20): an animation's frames trace the rest-frame geometry
built for an earlier frame wherever it is unchanged, with the pixels of a fresh build."""

import dataclasses
import pickle

import numpy as np
import pytest
from test_prepared import assemble, assert_same_passes, busy_scene, settings

from restframe_addon.core import frames as frames_module
from restframe_addon.core.persistent import GeometryCache
from restframe_addon.core.prepared import build_unmeasured, measured_as, prepare
from restframe_addon.core.render import render_tiles
from restframe_addon.core.scene import Velocity

FRAME_TIMES = (9.0, 9.5, 10.0)  # tau_obs of three frames of an animation (light_speed 1)
# busy_scene has five geometries: the floor (at rest), the cube and the ball (two velocities),
# the spinner (spinning) and the comet (animated: segments sharing one geometry)


@pytest.fixture
def builds(monkeypatch):
    """The geometry builds (embree scenes made), each as the object indices of its parts."""
    built = []
    geometry = frames_module._geometry

    def counted(parts, *args, **kwargs):
        built.append(tuple(sorted({int(i) for p in parts for i in np.unique(p["object_index"])})))
        return geometry(parts, *args, **kwargs)

    monkeypatch.setattr(frames_module, "_geometry", counted)
    return built


def render(prepared):
    return assemble(prepared, render_tiles(prepared))


def at(scene, tau_obs, **changes):
    """The scene at another frame's time, its meshes read anew (new arrays, as each frame's export
    makes) with some fields changed (mesh name -> Mesh fields)."""
    meshes = [dataclasses.replace(m, **{"vertices": m.vertices.copy(), "triangles": m.triangles.copy(),
                                         **changes.get(m.name, {})}) for m in scene.meshes]
    return dataclasses.replace(scene, tau_obs=tau_obs, meshes=meshes)


def test_frames_of_an_animation_reuse_every_body_and_render_the_same_bits(builds):
    scene, cache = busy_scene(), GeometryCache()
    for number, tau in enumerate(FRAME_TIMES):
        frame = at(scene, tau)
        before = len(builds)
        cached = render(prepare(frame, settings(), geometry_cache=cache))
        assert len(builds) - before == (5 if number == 0 else 0)
        fresh = render(prepare(frame, settings()))
        assert_same_passes(cached, fresh)
    assert (cache.builds, cache.reuses, len(cache)) == (5, 10, 5)
    first, last = (render(prepare(at(scene, tau), settings())) for tau in (FRAME_TIMES[0], FRAME_TIMES[-1]))
    assert not np.array_equal(first["Combined"], last["Combined"])  # the frames do differ


def test_a_deforming_body_is_built_again_and_the_others_are_reused(builds):
    scene, cache = busy_scene(), GeometryCache()
    prepare(at(scene, FRAME_TIMES[0]), settings(), geometry_cache=cache)
    cube = next(m for m in scene.meshes if m.name == "cube")
    squashed = cube.vertices * np.array([1.0, 1.0, 0.6]) + np.array([0.0, 0.0, -0.4])
    frame = at(scene, FRAME_TIMES[1], cube={"vertices": squashed})
    builds.clear()
    cached = render(prepare(frame, settings(), geometry_cache=cache))
    assert builds == [(2,)]  # the cube's object index: only its rest frame was built again
    assert (cache.builds, cache.reuses) == (6, 4)
    assert_same_passes(cached, render(prepare(frame, settings())))
    stale = render(prepare(at(scene, FRAME_TIMES[1]), settings()))
    assert not np.array_equal(cached["Combined"], stale["Combined"])  # the squashed cube shows


def changed_cube(scene):
    """Every kind of change to the cube that alters its geometry (name -> Mesh fields)."""
    cube = next(m for m in scene.meshes if m.name == "cube")
    n = len(cube.triangles)
    normals = np.tile(np.array([0.0, 0.0, 1.0]), (n, 3, 1))
    return {
        "vertices": {"vertices": cube.vertices + 1e-9},
        "triangles": {"triangles": cube.triangles[:, ::-1]},
        "material": {"material_indices": np.full(n, 2)},
        "normals": {"corner_normals": normals},
        "uvs": {"corner_uvs": np.zeros((n, 3, 2))},
        "object index": {"object_index": 7},
        "pivot": {"pivot": (-1.5, 6.0, 0.0)},  # contracted (along x) about another point
        "speed": {"velocity": Velocity((0.65, 0.0, 0.0))},  # another shift into its frame and clock
    }


@pytest.mark.parametrize("change", list(changed_cube(busy_scene())))
def test_any_change_to_a_body_builds_it_again(builds, change):
    scene, cache = busy_scene(), GeometryCache()
    prepare(at(scene, FRAME_TIMES[0]), settings(), geometry_cache=cache)
    builds.clear()
    frame = at(scene, FRAME_TIMES[1], cube=changed_cube(scene)[change])
    cached = render(prepare(frame, settings(), geometry_cache=cache))
    assert len(builds) == 1 and cache.reuses == 4
    assert_same_passes(cached, render(prepare(frame, settings())))


def test_the_cache_keeps_only_what_the_last_frame_used():
    scene, cache = busy_scene(), GeometryCache()
    prepare(at(scene, FRAME_TIMES[0]), settings(), geometry_cache=cache)
    assert len(cache) == 5
    without_cube = dataclasses.replace(at(scene, FRAME_TIMES[1]), meshes=[m for m in scene.meshes if m.name != "cube"])
    prepare(without_cube, settings(), geometry_cache=cache)
    assert len(cache) == 4
    cube = next(m for m in scene.meshes if m.name == "cube")
    moved = at(scene, FRAME_TIMES[2], cube={"vertices": cube.vertices + 0.1})
    prepare(moved, settings(), geometry_cache=cache)
    assert len(cache) == 5 and cache.builds == 6


def test_a_cancelled_build_keeps_what_was_built_and_forgets_nothing(builds):
    scene, cache = busy_scene(), GeometryCache()
    prepare(at(scene, FRAME_TIMES[0]), settings(), geometry_cache=cache)
    cube = next(m for m in scene.meshes if m.name == "cube")
    frame = at(scene, FRAME_TIMES[1], cube={"vertices": cube.vertices * 1.1})
    builds.clear()
    stop_in_the_cubes_build = lambda: (2,) in builds  # noqa: E731
    frames_module.build_frames(frame, should_stop=stop_in_the_cubes_build, geometry_cache=cache)
    assert builds == [(2,)] and len(cache) == 5  # the cancelled build not kept, the unvisited bodies not forgotten
    builds.clear()
    frames_module.build_frames(frame, geometry_cache=cache)
    assert builds == [(2,)] and len(cache) == 5


def test_a_prepared_scene_built_from_the_cache_pickles_and_rebuilds_the_same_pixels():
    scene, cache = busy_scene(), GeometryCache()
    prepare(at(scene, FRAME_TIMES[0]), settings(), geometry_cache=cache)
    prepared = prepare(at(scene, FRAME_TIMES[1]), settings(doppler_mode="FACTOR"), geometry_cache=cache)
    assert cache.reuses == 5
    rebuilt = pickle.loads(pickle.dumps(prepared))
    assert rebuilt.doppler_range == prepared.doppler_range
    assert_same_passes(render(prepared), render(rebuilt))


def test_a_worker_building_frame_after_frame_through_its_cache_builds_once(builds):
    """As a worker process builds each frame from its pickled scene and settings, then takes the
    measured values of the preparing process."""
    scene = busy_scene()
    frames = [prepare(at(scene, tau), settings(doppler_mode="FACTOR")) for tau in FRAME_TIMES]
    worker_cache, counts = GeometryCache(), []
    for prepared in frames:
        before = len(builds)
        built = build_unmeasured(*pickle.loads(pickle.dumps((prepared.scene, prepared.settings))), worker_cache)
        counts.append(len(builds) - before)
        assert_same_passes(render(measured_as(built, prepared.measurements)), render(prepared))
    before = len(builds)
    pickle.loads(pickle.dumps(frames[0]))  # unpickled: built afresh
    assert counts == [5, 0, 0] and len(builds) - before == 5

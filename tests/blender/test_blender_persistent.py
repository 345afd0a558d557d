"""Persistent Data (issue 20): with the scene's Persistent Data on, Blender keeps the engine from
frame to frame and bodies unchanged in their rest frames are not built again; the command line
does that for its frames by default.  The pixels are those of fresh renders."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, read_exr, render_exr
from restframe_addon.__main__ import main
from restframe_addon.core import frames as frames_module

FRAMES = (1, 2, 3)


@pytest.fixture
def builds(monkeypatch):
    """Geometry builds (embree scenes made) so far."""
    built = []
    geometry = frames_module._geometry

    def counted(parts, *args, **kwargs):
        built.append(len(parts))
        return geometry(parts, *args, **kwargs)

    monkeypatch.setattr(frames_module, "_geometry", counted)
    return built


@pytest.fixture
def animation(scene):
    """A floor at rest and a red plate at 0.6c seen from above: the plate moves 0.25 units a frame
    (frames 1..3 see it near where it was placed: its light takes 0.8 s to the camera)."""
    scene.render.fps, scene.render.fps_base = 24, 1.0
    scene.restframe.reference_frame = -18
    add_camera(scene, (0.0, 0.0, 8.0))
    add_sun(scene, rotation=(math.radians(25), 0.0, 0.0))
    add_plane(scene, "Floor", size=12.0, location=(0.0, 0.0, -1.0))
    plate = add_plane(scene, "Plate", size=2.0, location=(-1.0, 0.0, 0.0), velocity=(0.6, 0.0, 0.0))
    red = bpy.data.materials.new("Red")
    if bpy.app.version < (5, 0, 0):
        red.use_nodes = True
    red.node_tree.nodes["Principled BSDF"].inputs["Base Color"].default_value = (0.9, 0.1, 0.1, 1.0)
    plate.data.materials.append(red)
    return scene


def render_frames(scene, tmp_path, builds, persistent, edit=lambda frame: None):
    """Render FRAMES as F12 renders; (passes, builds) per frame."""
    scene.render.use_persistent_data = persistent
    out = []
    for frame in FRAMES:
        edit(frame)
        scene.frame_set(frame)
        before = len(builds)
        passes = render_exr(scene, tmp_path / f"{persistent}_{frame}.exr")
        out.append((passes, len(builds) - before))
    return out


def assert_same_pixels(a, b):
    assert a.keys() == b.keys()
    for name in a:
        assert np.array_equal(a[name], b[name]), name


def test_persistent_data_builds_unchanged_bodies_once_with_the_same_pixels(animation, tmp_path, builds):
    kept = render_frames(animation, tmp_path, builds, persistent=True)
    fresh = render_frames(animation, tmp_path, builds, persistent=False)
    assert [count for _, count in kept] == [2, 0, 0]
    assert [count for _, count in fresh] == [2, 2, 2]
    for (a, _), (b, _) in zip(kept, fresh):
        assert_same_pixels(a, b)
    assert not np.array_equal(kept[0][0]["Combined"], kept[-1][0]["Combined"])  # the plate moves


def test_a_mesh_edited_between_frames_is_built_again_alone(animation, tmp_path, builds):
    plate = animation.objects["Plate"].data

    def stretch(frame):  # each frame the plate is longer: a deforming body
        plate.vertices[1].co.x = plate.vertices[2].co.x = 1.0 + 0.3 * frame
        plate.update()

    kept = render_frames(animation, tmp_path, builds, persistent=True, edit=stretch)
    fresh = render_frames(animation, tmp_path, builds, persistent=False, edit=stretch)
    assert [count for _, count in kept] == [2, 1, 1]  # the floor is reused
    for (a, _), (b, _) in zip(kept, fresh):
        assert_same_pixels(a, b)


def test_the_command_line_reuses_the_geometry_of_its_frames(animation, tmp_path, builds):
    blend = tmp_path / "animation.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend), copy=True)
    counts = {}
    for option in ((), ("--no-persistent-data",)):
        before = len(builds)
        assert main(["render", str(blend), "-o", str(tmp_path / f"cli{len(option)}_#.exr"), "--frames", "1-3",
                     *option]) == 0
        counts[option] = len(builds) - before
    assert counts == {(): 2, ("--no-persistent-data",): 6}
    for frame in FRAMES:
        assert_same_pixels(read_exr(tmp_path / f"cli0_{frame}.exr"), read_exr(tmp_path / f"cli1_{frame}.exr"))


def test_the_exporter_reads_the_triangles_and_materials_blender_lists(scene):
    """read_mesh takes its arrays from attributes (contiguous storage): the same values as the
    loop triangles' own per-element fields, for quads and n-gons, several materials, a modifier."""
    from restframe_addon.export.features import FeatureReport
    from restframe_addon.export.materials import MaterialExporter
    from restframe_addon.export.meshes import read_mesh

    mesh = bpy.data.meshes.new("Mixed")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0), (2, 0, 0), (2.5, 0.5, 0), (2, 1, 0.3),
                      (1.5, 1.4, 0.1)], [], [(0, 1, 2, 3), (1, 4, 5, 6, 7, 2), (0, 3, 2)])
    obj = bpy.data.objects.new("Mixed", mesh)
    scene.collection.objects.link(obj)
    for name in ("A", "B", "C"):
        mesh.materials.append(bpy.data.materials.new(name))
    mesh.polygons[1].material_index = 2
    mesh.polygons[2].material_index = 1
    obj.modifiers.new("Subdivide", 'SUBSURF').levels = 1
    evaluated = obj.evaluated_get(bpy.context.evaluated_depsgraph_get())
    materials = MaterialExporter(lambda message: None, scene, unsupported=FeatureReport())
    data = read_mesh(evaluated, evaluated.data, materials)

    tris = evaluated.data.loop_triangles
    vertices = np.array([v.co for v in evaluated.data.vertices])
    assert np.array_equal(data.vertices, vertices.astype(np.float32).astype(np.float64))
    assert np.array_equal(data.triangles, np.array([t.vertices for t in tris]))
    slots = np.array([t.material_index for t in tris])
    assert set(slots) == {0, 1, 2}
    by_slot = np.array([materials.index_of(slot.material) for slot in evaluated.material_slots])
    assert len(set(by_slot)) == 3 and np.array_equal(data.materials, by_slot[slots])

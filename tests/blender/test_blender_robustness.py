"""Odd scenes through the render engine (issue 9): a correct image or one clear message, nothing lost."""

import hashlib
import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, export_now, render_exr
from restframe_addon import engine


def render():
    bpy.ops.render.render()
    return bpy.data.images["Render Result"]


@pytest.mark.parametrize("velocity, lorentz, message", [
    ((0.0, 1.0, 0.0), 0.0, "Tachyon: speed 1 c is not below the speed of light"),
    ((math.nan, 0.0, 0.0), 0.0, "Tachyon: the velocity .* is not a finite number"),
    ((math.inf, 0.0, 0.0), 0.0, "Tachyon: speed 3.40282.e\\+38 c is not below"),  # float32 clamps inf
    ((0.1, 0.0, 0.0), 0.5, "Tachyon: a Lorentz factor must be at least 1"),
    ((0.0, 0.0, 0.0), 3.0, "Tachyon: a Lorentz factor above 1 needs a velocity"),
])
def test_unphysical_velocity_is_an_error_naming_the_object(scene, velocity, lorentz, message):
    add_camera(scene)
    plane = add_plane(scene, "Tachyon")
    plane.restframe.velocity = velocity
    plane.restframe.lorentz_factor = lorentz
    with pytest.raises(RuntimeError, match=message):
        render()


def test_no_camera_is_an_error(scene):
    add_plane(scene)
    with pytest.raises(RuntimeError, match="no camera"):
        render()


def test_zero_resolution_is_refused(scene, tmp_path):
    add_camera(scene)
    scene.render.resolution_x = scene.render.resolution_y = 4
    scene.render.resolution_percentage = 1  # 4 * 1 % = 0 pixels
    with pytest.raises(RuntimeError):
        render()
    scene.render.resolution_percentage = 100
    assert render_exr(scene, tmp_path / "four.exr")["Doppler"].shape == (4, 4, 1)  # and the next render works


def test_light_speed_cannot_be_zero_or_negative(scene, tmp_path):
    add_camera(scene)
    add_sun(scene)
    add_plane(scene, velocity=(0.5, 0.0, 0.0))
    for value in (0.0, -3.0):
        scene.restframe.light_speed = value
        assert scene.restframe.light_speed == pytest.approx(1e-9)  # clamped by the property
    passes = render_exr(scene, tmp_path / "slow_light.exr")
    assert np.all(np.isfinite(passes["Combined"]))


def test_empty_scene_and_objects_without_faces(scene, tmp_path):
    add_camera(scene)
    world = bpy.data.worlds.new("W")
    world.color = (0.2, 0.3, 0.4)
    scene.world = world
    mesh = bpy.data.meshes.new("Wire")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0)], [(0, 1), (1, 2)], [])
    scene.collection.objects.link(bpy.data.objects.new("Wire", mesh))
    scene.collection.objects.link(bpy.data.objects.new("Empty Mesh", bpy.data.meshes.new("Nothing")))
    out, _, warnings = export_now(scene)
    assert out.meshes == [] and warnings == []
    passes = render_exr(scene, tmp_path / "empty.exr")
    assert np.all(passes["Doppler"] == 0.0)
    assert np.all(np.isfinite(passes["Combined"])) and passes["Combined"][..., :3].max() > 0


def test_degenerate_and_nan_geometry_renders_with_a_warning(scene, tmp_path):
    add_camera(scene)
    add_sun(scene)
    add_plane(scene, "Good", size=3.0)
    bad = bpy.data.meshes.new("Bad")
    bad.from_pydata([(0, 0, 1), (1, 0, 1), (2, 0, 1), (0, 1, 1), (math.nan, 0, 1), (0, 2, 1)], [],
                    [(0, 1, 2), (0, 0, 3), (3, 4, 5)])  # collinear, repeated vertex, a NaN corner
    scene.collection.objects.link(bpy.data.objects.new("Bad", bad))
    passes = render_exr(scene, tmp_path / "bad.exr")
    assert np.all(np.isfinite(passes["Combined"])) and (passes["Doppler"] > 0).sum() > 20
    out, settings, _ = export_now(scene)
    from restframe_addon.core.prepared import prepare
    warnings = prepare(out, settings).warnings
    assert any(w.startswith("Bad: skipped") for w in warnings)


def test_unsupported_material_falls_back_and_says_so_once(scene):
    add_camera(scene)
    mat = bpy.data.materials.new("Velvet")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    tree.nodes.remove(tree.nodes["Principled BSDF"])
    sheen = tree.nodes.new("ShaderNodeBsdfSheen")
    tree.links.new(sheen.outputs[0], tree.nodes["Material Output"].inputs["Surface"])
    mat.diffuse_color = (0.2, 0.4, 0.6, 1.0)
    for i in range(3):
        add_plane(scene, f"P{i}", location=(i, 0, 0)).data.materials.append(mat)
    out, _, warnings = export_now(scene)
    assert len([w for w in warnings if "Velvet" in w]) == 1
    assert "not supported" in warnings[0]
    assert out.materials[1].base_color == pytest.approx((0.2, 0.4, 0.6))


def test_missing_image_texture_uses_the_base_colour(scene, tmp_path):
    add_camera(scene)
    add_sun(scene)
    mat = bpy.data.materials.new("Photo")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    tree = mat.node_tree
    image = bpy.data.images.new("gone", 4, 4)
    image.source = 'FILE'
    image.filepath = str(tmp_path / "does_not_exist.png")
    node = tree.nodes.new("ShaderNodeTexImage")
    node.image = image
    tree.links.new(node.outputs["Color"], tree.nodes["Principled BSDF"].inputs["Base Color"])
    add_plane(scene, size=3.0).data.materials.append(mat)
    out, _, warnings = export_now(scene)
    assert any("could not be loaded" in w and "does_not_exist.png" in w for w in warnings)
    assert out.materials[1].base_color_texture is None
    passes = render_exr(scene, tmp_path / "photo.exr")
    assert (passes["Doppler"] > 0).sum() > 20 and np.all(np.isfinite(passes["Combined"]))


def test_light_inside_an_object_and_camera_inside_an_object(scene, tmp_path):
    add_camera(scene, location=(0.0, 0.0, 0.3))
    bpy.ops.mesh.primitive_cube_add(size=4.0)
    lamp = bpy.data.objects.new("Lamp", bpy.data.lights.new("Lamp", 'POINT'))
    lamp.location = (0.5, 0.5, 0.5)
    scene.collection.objects.link(lamp)
    passes = render_exr(scene, tmp_path / "inside.exr")
    assert np.all(passes["Doppler"] > 0)  # every ray meets the cube from inside
    assert np.all(np.isfinite(passes["Combined"])) and passes["Combined"][..., :3].max() > 0


# --------------------------------------------------------------------------- cancel
def _esc_at(stage, monkeypatch):
    """Press Esc (``test_break`` true from then on) once the render reaches a stage: at once
    ("export"), after the export ("build"), or after the first tile ("render").  Counts the tiles
    the engine receives after Esc."""
    state = {"esc": stage == "export", "tiles_after_esc": 0, "tiles": 0}
    export_scene, render_tiles = engine.export.export_scene, engine.render_tiles

    def exported(*args, **kwargs):
        result = export_scene(*args, **kwargs)
        state["esc"] = state["esc"] or stage == "build"
        return result

    def tiles(*args, **kwargs):
        for tile in render_tiles(*args, **kwargs):
            state["tiles"] += 1
            state["tiles_after_esc"] += state["esc"]
            state["esc"] = state["esc"] or stage == "render"
            yield tile

    monkeypatch.setattr(engine.export, "export_scene", exported)
    monkeypatch.setattr(engine, "render_tiles", tiles)
    monkeypatch.setattr(engine.RestframeRenderEngine, "should_stop", lambda self=None: state["esc"])
    return state


@pytest.mark.parametrize("stage", ["export", "build", "render"])
def test_cancel_stops_at_the_stage_it_is_pressed_and_the_next_render_works(scene, monkeypatch, tmp_path, stage):
    """Esc (``test_break``) during export, frame building or rendering: no tile is delivered after it,
    nothing is left behind, and the next render is complete.  (How fast it returns is measured by
    tests/robustness/measure_cancel.py, not asserted here.)"""
    add_camera(scene, location=(0.0, -8.0, 2.0), rotation=(math.radians(80), 0.0, 0.0))
    add_sun(scene)
    scene.render.resolution_x, scene.render.resolution_y = 160, 120
    scene.restframe.samples = 8
    scene.restframe.tile_size = 32
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1  # tiles one at a time: a count, not a race
    for i in range(6):
        bpy.ops.mesh.primitive_uv_sphere_add(segments=64, ring_count=32, location=(2 * i - 5, 0, 0))
        bpy.context.active_object.restframe.velocity = (0.0, 0.1 * i, 0.0)
    runner = add_plane(scene, "Runner", location=(0, 3, 0))
    runner.keyframe_insert("location", frame=1)
    runner.location = (3.0, 3.0, 0.0)
    runner.keyframe_insert("location", frame=25)
    runner.restframe.motion = 'ANIMATION'
    meshes = len(bpy.data.meshes)
    state = _esc_at(stage, monkeypatch)
    bpy.ops.render.render()
    assert state["esc"]
    assert state["tiles"] == (1 if stage == "render" else 0)  # of 20: not one more after Esc
    assert state["tiles_after_esc"] == 0
    assert len(bpy.data.meshes) == meshes
    monkeypatch.undo()
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    scene.restframe.samples = 1
    passes = render_exr(scene, tmp_path / "again.exr")
    assert passes["Doppler"].shape == (24, 32, 1)
    assert (passes["Doppler"] > 0).sum() > 50 and np.all(np.isfinite(passes["Combined"]))


# --------------------------------------------------------------------------- nothing lost
def _digest(path):
    return hashlib.sha256(path.read_bytes()).hexdigest()


def _fingerprint():
    """The user's data as numbers: meshes, object transforms and settings, animation, scene state."""
    h = hashlib.sha256()
    for mesh in bpy.data.meshes:
        co = np.empty(len(mesh.vertices) * 3)
        mesh.vertices.foreach_get("co", co)
        h.update(mesh.name.encode() + co.tobytes())
    for obj in bpy.data.objects:
        rf = obj.restframe
        values = [*obj.location, *obj.rotation_euler, *obj.scale, *rf.velocity, rf.lorentz_factor,
                  *rf.angular_velocity, len(obj.modifiers)]
        h.update(obj.name.encode() + rf.motion.encode() + np.array(values, float).tobytes())
    for action in bpy.data.actions:
        h.update(action.name.encode())
    for scene in bpy.data.scenes:
        h.update(np.array([scene.frame_current, scene.frame_subframe, scene.restframe.light_speed,
                           scene.render.resolution_x], float).tobytes())
    return h.hexdigest()


def test_rendering_changes_nothing_in_the_file_or_the_data(scene, tmp_path):
    """A headless F12 leaves the .blend on disk byte-identical, adds or removes no data-block (no
    temporary meshes), changes no value and leaves nothing unsaved."""
    add_camera(scene)
    add_sun(scene)
    moving = add_plane(scene, "Moving", velocity=(0.6, 0.0, 0.0))
    moving.restframe.angular_velocity = (0.0, 0.0, 1.0)
    runner = add_plane(scene, "Runner", location=(0, 2, 0))
    runner.keyframe_insert("location", frame=1)
    runner.location = (1.0, 2.0, 0.0)
    runner.keyframe_insert("location", frame=25)
    runner.restframe.motion = 'ANIMATION'
    bpy.ops.mesh.primitive_monkey_add(location=(0, -1, 0))
    bpy.context.active_object.modifiers.new("Smooth", 'SUBSURF')
    blend = tmp_path / "work.blend"
    bpy.ops.wm.save_as_mainfile(filepath=str(blend))
    bpy.ops.wm.open_mainfile(filepath=str(blend))
    scene = bpy.context.scene
    scene.frame_set(7)
    before = _digest(blend)
    counts = {name: len(getattr(bpy.data, name)) for name in ("meshes", "objects", "materials", "actions", "scenes")}
    fingerprint = _fingerprint()
    bpy.ops.render.render(write_still=False)
    assert counts == {name: len(getattr(bpy.data, name)) for name in counts}
    assert _fingerprint() == fingerprint
    assert _digest(blend) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["work.blend"]  # no backup or temporary files

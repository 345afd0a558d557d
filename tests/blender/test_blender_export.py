"""Export of the evaluated depsgraph into the core's scene description."""

import math
import os
import subprocess
import sys

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, evaluated, export_now, principled
from restframe_addon import export, motion_query


def by_name(meshes, name):
    found = [m for m in meshes if m.name == name]
    assert len(found) == 1, [m.name for m in meshes]
    return found[0]


def data_counts():
    return {name: len(getattr(bpy.data, name)) for name in ("meshes", "objects", "materials", "images", "curves")}


def test_modifier_stack_is_applied_without_touching_the_original(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(1.0, 2.0, 3.0), rotation=(0.1, 0.2, 0.3))
    cube = bpy.context.object
    cube.scale = (1.0, 2.0, 0.5)
    array = cube.modifiers.new("Array", 'ARRAY')
    array.count = 3
    cube.modifiers.new("Subdivision", 'SUBSURF').levels = 1
    cube.modifiers.new("Triangulate", 'TRIANGULATE')
    before = data_counts()

    out, _, _ = export_now(scene)
    mesh = by_name(out.meshes, "Cube")
    ev = cube.evaluated_get(evaluated(scene)).data
    assert len(mesh.triangles) == len(ev.loop_triangles) == len(ev.polygons) > 3 * 6 * 4
    co = np.array([v.co for v in ev.vertices])
    world = co @ np.array(cube.matrix_world)[:3, :3].T + np.array(cube.matrix_world)[:3, 3]
    np.testing.assert_allclose(mesh.vertices, world, atol=1e-5)
    assert mesh.vertices.dtype == np.float64 and mesh.vertices.shape == (len(ev.vertices), 3)
    assert mesh.triangles.max() < len(mesh.vertices)
    # flat-shaded: the tracer's geometric normals are exact, no corner normals needed
    assert mesh.corner_normals is None
    assert len(cube.data.vertices) == 8 and data_counts() == before


def test_smooth_normals_follow_the_object_transform(scene):
    add_camera(scene)
    bpy.ops.mesh.primitive_uv_sphere_add(segments=12, ring_count=6, radius=1.0, location=(0, 0, 0))
    sphere = bpy.context.object
    bpy.ops.object.shade_smooth()
    sphere.scale = (1.0, 1.0, 3.0)
    out, _, _ = export_now(scene)
    mesh = by_name(out.meshes, "Sphere")
    assert mesh.corner_normals.shape == (len(mesh.triangles), 3, 3)
    np.testing.assert_allclose(np.linalg.norm(mesh.corner_normals, axis=2), 1.0, atol=1e-6)
    # an ellipsoid stretched along z: the normal at a vertex is the gradient x/1, y/1, z/9
    corner = mesh.vertices[mesh.triangles]
    expected = corner * np.array([1.0, 1.0, 1.0 / 9.0])
    expected /= np.linalg.norm(expected, axis=2, keepdims=True)
    assert np.mean(np.sum(expected * mesh.corner_normals, axis=2)) > 0.99


def test_collection_instance_moves_with_its_instancer(scene):
    add_camera(scene)
    source = bpy.data.collections.new("Source")
    scene.collection.children.link(source)
    mesh = bpy.data.meshes.new("Box")
    mesh.from_pydata([(0, 0, 0), (1, 0, 0), (1, 1, 0), (0, 1, 0)], [], [(0, 1, 2, 3)])
    box = bpy.data.objects.new("Box", mesh)
    box.location = (0.5, 0.0, 0.0)
    source.objects.link(box)
    scene.view_layers[0].layer_collection.children["Source"].exclude = True  # only the instance shows

    empty = bpy.data.objects.new("Instancer", None)
    empty.instance_type = 'COLLECTION'
    empty.instance_collection = source
    empty.location = (10.0, 0.0, 0.0)
    empty.rotation_euler = (0.0, 0.0, math.pi / 2)
    empty.restframe.velocity = (0.5, 0.0, 0.0)
    scene.collection.objects.link(empty)

    out, _, _ = export_now(scene)
    assert [m.name for m in out.meshes] == ["Instancer/Box"]
    inst = out.meshes[0]
    # rotated 90 degrees about z around the instancer: (x, y) -> (-y, x), then moved
    expected = np.array([(10.0, 0.5, 0.0), (10.0, 1.5, 0.0), (9.0, 1.5, 0.0), (9.0, 0.5, 0.0)])
    np.testing.assert_allclose(inst.vertices, expected, atol=1e-6)
    assert inst.velocity.beta == (0.5, 0.0, 0.0)
    assert inst.pivot == pytest.approx((10.0, 0.0, 0.0))


def test_text_and_curve_arrive_as_triangles(scene):
    add_camera(scene)
    bpy.ops.object.text_add(location=(3.0, 0.0, 1.0))
    text = bpy.context.object
    text.data.body = "Hi"
    text.restframe.velocity = (0.0, 0.6, 0.0)
    bpy.ops.curve.primitive_bezier_circle_add(radius=1.0, location=(-3.0, 0.0, 0.0))
    curve = bpy.context.object
    curve.data.bevel_depth = 0.1
    bpy.ops.curve.primitive_bezier_curve_add(location=(0.0, 5.0, 0.0))  # no bevel: no surface
    before = data_counts()

    out, _, _ = export_now(scene)
    names = sorted(m.name for m in out.meshes)
    assert names == ["BézierCircle/BézierCircle", "Text/Text"]
    text_mesh = by_name(out.meshes, "Text/Text")
    assert len(text_mesh.triangles) > 10
    assert np.allclose(text_mesh.vertices[:, 2], 1.0)  # flat text in its plane at z = 1
    assert text_mesh.vertices[:, 0].min() >= 3.0 - 1e-6
    assert text_mesh.velocity.beta == pytest.approx((0.0, 0.6, 0.0))
    assert text_mesh.pivot == pytest.approx((3.0, 0.0, 1.0))
    tube = by_name(out.meshes, "BézierCircle/BézierCircle")
    radius = np.linalg.norm(tube.vertices[:, :2] - (-3.0, 0.0), axis=1)
    assert radius.min() == pytest.approx(0.9, abs=0.02) and radius.max() == pytest.approx(1.1, abs=0.02)
    assert data_counts() == before


def test_assembly_pivot_is_the_topmost_parent_with_the_same_velocity(scene):
    add_camera(scene)
    parent = add_plane(scene, "Parent", location=(1.0, 2.0, 3.0), velocity=(0.5, 0.0, 0.0))
    child = add_plane(scene, "Child", location=(4.0, 0.0, 0.0), velocity=(0.5, 0.0, 0.0))
    child.parent = parent
    other = add_plane(scene, "Other", location=(0.0, 7.0, 0.0), velocity=(0.0, 0.5, 0.0))
    other.parent = child
    out, _, _ = export_now(scene)
    assert by_name(out.meshes, "Parent").pivot == pytest.approx((1.0, 2.0, 3.0))
    assert by_name(out.meshes, "Child").pivot == pytest.approx((1.0, 2.0, 3.0))
    assert by_name(out.meshes, "Other").pivot == pytest.approx(tuple(other.matrix_world.translation))


def test_principled_materials_textures_and_fallbacks(scene):
    add_camera(scene)
    a = add_plane(scene, "A")
    a.data.materials.append(principled("Gold", **{
        "Base Color": (0.9, 0.6, 0.2, 1.0), "Metallic": 1.0, "Roughness": 0.25, "IOR": 1.33,
        "Specular IOR Level": 0.7,
        "Transmission Weight": 0.5, "Emission Color": (1.0, 0.5, 0.0, 1.0), "Emission Strength": 4.0}))

    image = bpy.data.images.new("Grid", 16, 8)
    image.generated_type = 'COLOR_GRID'
    textured = principled("Textured")
    tex = textured.node_tree.nodes.new("ShaderNodeTexImage")
    tex.image = image
    textured.node_tree.links.new(tex.outputs["Color"], textured.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    b = add_plane(scene, "B", location=(5, 0, 0))
    b.data.uv_layers.new(name="UVMap")
    b.data.materials.append(textured)

    glass = bpy.data.materials.new("Odd")
    if bpy.app.version < (5, 0, 0):
        glass.use_nodes = True
    nodes = glass.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    toon = nodes.new("ShaderNodeBsdfGlass")
    glass.node_tree.links.new(toon.outputs[0], nodes["Material Output"].inputs["Surface"])
    glass.diffuse_color = (0.1, 0.2, 0.3, 1.0)
    for i in range(2):
        add_plane(scene, f"Odd{i}", location=(0, 5 + 5 * i, 0)).data.materials.append(glass)
    add_plane(scene, "Bare", location=(-5, 0, 0))

    out, _, warnings = export_now(scene)
    materials = {m.name: m for m in out.materials}
    gold = materials["Gold"]
    assert gold.base_color == pytest.approx((0.9, 0.6, 0.2))
    assert (gold.metallic, gold.roughness, gold.ior, gold.transmission) == pytest.approx((1.0, 0.25, 1.33, 0.5))
    assert gold.emission == pytest.approx((4.0, 2.0, 0.0))
    assert gold.specular_ior_level == pytest.approx(0.7)
    assert all(out.materials[i] is gold for i in by_name(out.meshes, "A").material_indices)

    texture = materials["Textured"].base_color_texture
    pixels = np.array(image.pixels[:], dtype=np.float32).reshape(8, 16, 4)[..., :3]
    srgb = pixels
    linear = np.where(srgb <= 0.04045, srgb / 12.92, ((srgb + 0.055) / 1.055) ** 2.4)
    assert texture.shape == (8, 16, 3)
    np.testing.assert_allclose(texture, linear, atol=1e-6)
    b_mesh = by_name(out.meshes, "B")
    assert b_mesh.corner_uvs.shape == (2, 3, 2)

    assert materials["Odd"].base_color == pytest.approx((0.1, 0.2, 0.3))
    assert sum("Odd" in w and "not supported" in w for w in warnings) == 1  # said once, not per object
    assert by_name(out.meshes, "Bare").material_indices.tolist() == [0, 0]
    assert out.materials[0].name == "Default"


def test_missing_image_falls_back_with_a_warning(scene, tmp_path):
    add_camera(scene)
    mat = principled("Missing", **{"Base Color": (0.2, 0.4, 0.6, 1.0)})
    tex = mat.node_tree.nodes.new("ShaderNodeTexImage")
    lost = bpy.data.images.new("Lost", 4, 4)
    lost.source = 'FILE'
    lost.filepath = str(tmp_path / "nowhere.png")  # as after the texture file was moved away
    tex.image = lost
    mat.node_tree.links.new(tex.outputs["Color"], mat.node_tree.nodes["Principled BSDF"].inputs["Base Color"])
    add_plane(scene).data.materials.append(mat)
    out, _, warnings = export_now(scene)
    missing = next(m for m in out.materials if m.name == "Missing")
    assert missing.base_color_texture is None and missing.base_color == pytest.approx((0.2, 0.4, 0.6))
    assert any("nowhere.png" in w for w in warnings)


def test_lights_world_and_camera(scene):
    cam = add_camera(scene, location=(1.0, 2.0, 3.0), lens=50.0, shift_x=0.1)
    cam.scale = (2.0, 2.0, 2.0)  # camera scale must not leak into the ray frame
    specs = {
        "Point": dict(type='POINT', energy=100.0, shadow_soft_size=0.5),
        "Spot": dict(type='SPOT', energy=200.0, spot_size=0.8, spot_blend=0.3),
        "Sun": dict(type='SUN', energy=3.0, angle=0.1),
        "Area": dict(type='AREA', energy=50.0, shape='RECTANGLE', size=2.0, size_y=0.5),
    }
    for name, spec in specs.items():
        data = bpy.data.lights.new(name, spec.pop("type"))
        for key, value in spec.items():
            setattr(data, key, value)
        obj = bpy.data.objects.new(name, data)
        obj.location = (0.0, 0.0, 5.0)
        scene.collection.objects.link(obj)
    bpy.data.objects["Area"].scale = (3.0, 1.0, 1.0)
    point = bpy.data.lights["Point"]
    if hasattr(point, "exposure"):
        point.exposure = 1.0
    else:  # Blender 4.2 has no light exposure: the same power through the energy
        point.energy *= 2.0
    has_temperature = hasattr(bpy.data.lights["Sun"], "use_temperature")  # Blender 4.5+
    if has_temperature:
        bpy.data.lights["Sun"].use_temperature = True
        bpy.data.lights["Sun"].temperature = 3000.0
    bpy.data.objects["Spot"].restframe.velocity = (0.0, 0.0, -0.3)
    world = bpy.data.worlds.new("W")
    scene.world = world
    if bpy.app.version < (5, 0, 0):  # always on from 5.0
        world.use_nodes = True
    background = world.node_tree.nodes["Background"]
    background.inputs["Color"].default_value = (0.1, 0.2, 0.4, 1.0)
    background.inputs["Strength"].default_value = 2.0

    out, settings, _ = export_now(scene)
    lights = {light.name: light for light in out.lights}
    assert lights["Point"].kind == 'POINT' and lights["Point"].power == pytest.approx(200.0)
    assert lights["Point"].radius == pytest.approx(0.5)
    assert (lights["Spot"].spot_size, lights["Spot"].spot_blend) == pytest.approx((0.8, 0.3))
    assert lights["Spot"].velocity.beta == pytest.approx((0.0, 0.0, -0.3))
    assert lights["Sun"].power == pytest.approx(3.0) and lights["Sun"].sun_angle == pytest.approx(0.1)
    assert lights["Sun"].temperature == (3000.0 if has_temperature else 0.0) and lights["Point"].temperature == 0.0
    assert lights["Area"].area_shape == 'RECTANGLE' and lights["Area"].area_size == pytest.approx((6.0, 0.5))
    assert lights["Point"].position == pytest.approx((0.0, 0.0, 5.0))
    assert out.world_color == pytest.approx((0.2, 0.4, 0.8))

    camera = out.camera
    np.testing.assert_allclose(camera.matrix[:3, 3], (1.0, 2.0, 3.0))
    np.testing.assert_allclose(camera.matrix[:3, :3], np.eye(3), atol=1e-12)
    frame = np.array([tuple(v) for v in cam.data.view_frame(scene=scene)])
    np.testing.assert_allclose(camera.frame, frame)
    assert camera.kind == 'PERSP' and camera.name == "Camera"
    assert settings.resolution == (21, 15) and settings.region is None


def test_render_settings_follow_the_scene(scene):
    add_camera(scene)
    rf = scene.restframe
    rf.samples, rf.max_bounces, rf.tile_size = 9, 3, 16
    rf.doppler_mode, rf.searchlight, rf.doppler_range_auto = 'FACTOR', False, False
    rf.doppler_range, rf.doppler_levels = (0.5, 2.0), 5
    rf.spectral_samples, rf.normalize_exposure = 12, True
    scene.render.resolution_percentage = 200
    scene.render.film_transparent = True
    scene.render.threads_mode, scene.render.threads = 'FIXED', 3
    assert rf.parallelism == 'PROCESSES'  # the default
    rf.parallelism = 'THREADS'
    _, settings, _ = export_now(scene)
    assert settings.parallelism == 'THREADS'
    assert settings.resolution == (42, 30)
    assert (settings.samples, settings.max_bounces, settings.tile_size, settings.threads) == (9, 3, 16, 3)
    assert (settings.doppler_mode, settings.searchlight, settings.doppler_levels) == ('FACTOR', False, 5)
    assert settings.doppler_range == pytest.approx((0.5, 2.0)) and settings.film_transparent
    assert settings.spectral_samples == 12 and settings.normalize_exposure


def test_observation_time_uses_subframes_and_fps_base(scene):
    scene.render.fps, scene.render.fps_base = 30, 1.001
    scene.restframe.reference_frame = 10
    scene.restframe.light_speed = 4.0
    scene.frame_set(25, subframe=0.5)
    fps_base = scene.render.fps_base  # stored in single precision
    assert fps_base == pytest.approx(1.001, rel=1e-7)
    assert motion_query.observation_time(scene) == pytest.approx(15.5 * fps_base / 30, rel=1e-15)
    add_camera(scene)
    out, _, _ = export_now(scene)
    assert out.tau_obs == pytest.approx(4.0 * 15.5 * 1.001 / 30, rel=1e-7)
    assert out.light_speed == 4.0


@pytest.mark.parametrize("velocity, gamma, message", [
    ((0.0, 0.0, 1.0), 0.0, "not below the speed of light"),
    ((0.8, 0.7, 0.0), 0.0, "not below the speed of light"),
    ((math.nan, 0.0, 0.0), 0.0, "not a finite number"),
    ((math.inf, 0.0, 0.0), 0.0, "not below the speed of light"),  # Blender stores inf as FLT_MAX
    ((1.0, 0.0, 0.0), 0.5, "at least 1"),
    ((0.0, 0.0, 0.0), 3.0, "needs a velocity"),
])
def test_invalid_velocities_name_the_object(scene, velocity, gamma, message):
    add_camera(scene)
    plane = add_plane(scene, "Rocket", velocity=velocity)
    plane.restframe.lorentz_factor = gamma
    with pytest.raises(export.ExportError, match=message) as error:
        export_now(scene)
    assert str(error.value).startswith("Rocket: ")


def test_huge_lorentz_factor_is_accepted(scene):
    add_camera(scene)
    plane = add_plane(scene, velocity=(0.0, 0.0, 1.0))  # direction only
    plane.restframe.lorentz_factor = 1e8
    out, _, _ = export_now(scene)
    assert out.meshes[0].velocity.lorentz_factor == 1e8


def test_no_camera_is_an_error(scene):
    add_plane(scene)
    with pytest.raises(export.ExportError, match="no camera"):
        export_now(scene)


def test_keyframed_location_with_velocity_warns(scene):
    add_camera(scene)
    plane = add_plane(scene, "Jumper", velocity=(0.3, 0.0, 0.0))
    plane.keyframe_insert("location", frame=1)
    still = add_plane(scene, "Still", location=(0, 5, 0))
    still.keyframe_insert("location", frame=1)  # animated but not moving relativistically: fine
    _, _, warnings = export_now(scene)
    assert len(warnings) == 1 and warnings[0].startswith("Jumper: ") and "keyframed location" in warnings[0]
    assert motion_query.has_animated_location(plane) and motion_query.has_animated_location(still)


def test_cancel_stops_the_export(scene):
    add_camera(scene)
    for i in range(3):
        add_plane(scene, f"P{i}", location=(i, 0, 0))
    calls = []

    def stop_on_second_check():
        calls.append(1)
        return len(calls) >= 2

    with pytest.raises(export.ExportCancelled):
        export_now(scene, should_stop=stop_on_second_check)
    assert len(calls) == 2


def nested_instances(scene, instanced=True):
    """Two empties A0, A1 at 0.5c along x instancing 'Outer' = {Wall (no velocity), B (an empty at
    0.3c along y instancing 'Inner' = {Box (no velocity), Probe (its own velocity)})}; with
    ``instanced`` False, the same geometry and velocities as plain objects instead."""
    def triangle(name, at, velocity=(0.0, 0.0, 0.0), collection=None):
        mesh = bpy.data.meshes.new(name)
        mesh.from_pydata([(-0.5, -0.5, 0), (0.5, -0.5, 0), (0.0, 0.5, 0)], [], [(0, 1, 2)])
        obj = bpy.data.objects.new(name, mesh)
        obj.location = at
        obj.restframe.velocity = velocity
        (collection or scene.collection).objects.link(obj)
        return obj

    if not instanced:
        for i in range(2):
            x = 4.0 * i
            triangle(f"A{i}/Wall", (x, 0, 0), (0.5, 0, 0))
            triangle(f"A{i}/Box", (x, 2, 0), (0.0, 0.3, 0))
            triangle(f"A{i}/Probe", (x + 1, 2, 0), (0.0, 0.0, -0.2))
        return

    def collection(name):
        c = bpy.data.collections.new(name)
        scene.collection.children.link(c)
        scene.view_layers[0].layer_collection.children[name].exclude = True
        return c

    inner, outer = collection("Inner"), collection("Outer")
    triangle("Box", (0, 0, 0), collection=inner)
    triangle("Probe", (1, 0, 0), (0.0, 0.0, -0.2), collection=inner)
    triangle("Wall", (0, 0, 0), collection=outer)
    b = bpy.data.objects.new("B", None)
    b.instance_type, b.instance_collection = 'COLLECTION', inner
    b.location = (0, 2, 0)
    b.restframe.velocity = (0.0, 0.3, 0.0)
    outer.objects.link(b)
    for i in range(2):
        a = bpy.data.objects.new(f"A{i}", None)
        a.instance_type, a.instance_collection = 'COLLECTION', outer
        a.location = (4.0 * i, 0, 0)
        a.restframe.velocity = (0.5, 0.0, 0.0)
        scene.collection.objects.link(a)


def test_nested_instancers_give_the_innermost_velocity(scene):
    """The innermost motion counts, as for parents: an instanced object's own velocity, else the
    nearest instancer's (B inside the instanced collection), else the top-level one's (A)."""
    add_camera(scene)
    nested_instances(scene)
    out, _, _ = export_now(scene)
    for i in range(2):
        x = 4.0 * i
        wall, box, probe = (by_name(out.meshes, f"A{i}/{name}") for name in ("Wall", "Box", "Probe"))
        assert wall.velocity.beta == pytest.approx((0.5, 0.0, 0.0)) and wall.pivot == pytest.approx((x, 0, 0))
        assert box.velocity.beta == pytest.approx((0.0, 0.3, 0.0)) and box.pivot == pytest.approx((x, 2, 0))
        assert probe.velocity.beta == pytest.approx((0.0, 0.0, -0.2)) and probe.pivot == pytest.approx((x + 1, 2, 0))


def test_nested_instances_render_like_the_same_plain_objects(scene, tmp_path):
    from blender_helpers import render_exr
    scene.render.resolution_x, scene.render.resolution_y = 60, 36
    add_camera(scene, location=(2.5, 1.0, 9.0))
    nested_instances(scene)
    nested = render_exr(scene, tmp_path / "nested.exr")["Doppler"]
    for obj in list(bpy.data.objects):
        if obj.type != 'CAMERA':
            bpy.data.objects.remove(obj)
    nested_instances(scene, instanced=False)
    plain = render_exr(scene, tmp_path / "plain.exr")["Doppler"]
    assert np.count_nonzero(plain) > 100 and len(np.unique(plain.round(4))) > 3
    np.testing.assert_allclose(nested, plain, rtol=1e-9, atol=0)


def test_the_ui_answers_motion_questions_without_the_exporter():
    """ui.py asks motion_query (and the core's checks), never the export package."""
    code = ("import sys, restframe_addon.ui; "
            "print(sorted(m for m in sys.modules if m.startswith('restframe_addon.export')))")
    root = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
    result = subprocess.run([sys.executable, "-c", code], cwd=root, capture_output=True, text=True, check=True)
    assert result.stdout.strip().splitlines()[-1] == "[]"

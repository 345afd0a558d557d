"""A red team of the render engine from the user's side: odd input gets one clear message naming
the object, the file is unchanged and nothing incomplete is written."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, export_now, principled, render_exr
from restframe_addon.export.features import UNSUPPORTED


@pytest.mark.parametrize("spoil, message", [
    (lambda: setattr(bpy.data.lights["Sun"], "energy", math.nan), "Sun: its power .* is not a finite number"),
    (lambda: setattr(bpy.data.lights["Sun"], "color", (1.0, math.nan, 1.0)), "Sun: its color"),
    (lambda: setattr(bpy.data.objects["Sun"], "rotation_euler", (math.nan, 0.0, 0.0)), "Sun: its world transform"),
    (lambda: setattr(bpy.data.objects["Camera"], "location", (0.0, math.nan, 10.0)), "Camera: its world transform"),
    (lambda: setattr(bpy.data.objects["Camera"], "scale", (0.0, 0.0, 0.0)), "Camera: its world transform"),
    (lambda: setattr(bpy.data.cameras["Camera"], "lens", math.nan), "Camera: its view frame"),
    (lambda: bpy.data.objects["Plane"].data.materials.append(principled("Paint", Roughness=math.nan)),
     "material Paint: its roughness"),
])
def test_a_nan_setting_stops_the_render_naming_the_object_and_writes_nothing(scene, tmp_path, spoil, message):
    add_camera(scene)
    add_plane(scene)
    add_sun(scene)
    spoil()
    path = tmp_path / "spoilt.exr"
    with pytest.raises(RuntimeError, match=message):
        render_exr(scene, path)
    assert not path.exists()


def _points(scene, name, xs, velocity):
    mesh = bpy.data.meshes.new(name)
    mesh.from_pydata([(x, 0.0, 0.0) for x in xs], [], [])
    obj = bpy.data.objects.new(name, mesh)
    obj.restframe.velocity = velocity
    scene.collection.objects.link(obj)
    return obj


def _instance_on_points(obj, instanced):
    """A geometry-nodes modifier putting ``instanced``'s geometry (Object Info, not as an instance of
    the object) on every point of ``obj``."""
    tree = bpy.data.node_groups.new("OnPoints", 'GeometryNodeTree')
    tree.interface.new_socket("Geometry", in_out='INPUT', socket_type='NodeSocketGeometry')
    tree.interface.new_socket("Geometry", in_out='OUTPUT', socket_type='NodeSocketGeometry')
    into, out = tree.nodes.new("NodeGroupInput"), tree.nodes.new("NodeGroupOutput")
    on_points, info = tree.nodes.new("GeometryNodeInstanceOnPoints"), tree.nodes.new("GeometryNodeObjectInfo")
    info.inputs["Object"].default_value = instanced
    tree.links.new(into.outputs[0], on_points.inputs["Points"])
    tree.links.new(info.outputs["Geometry"], on_points.inputs["Instance"])
    tree.links.new(on_points.outputs[0], out.inputs[0])
    obj.modifiers.new("OnPoints", 'NODES').node_group = tree


def test_geometry_nodes_instances_contract_with_their_instancer_as_one_body(scene, tmp_path):
    """Squares put on the points of a mesh moving at 0.8 c by geometry nodes are one body with it:
    seen as the same squares in one plain mesh at that velocity (contracted about the mesh's origin,
    their spacing too), not each about its own point."""
    scene.render.resolution_x, scene.render.resolution_y = 96, 24  # 0.09 units a pixel
    add_camera(scene, location=(-9.0, 0.0, 12.0))  # above where the squares were when the light left them
    add_sun(scene)
    square = bpy.data.objects.new("Square", bpy.data.meshes.new("Square"))  # in no scene: only instanced
    square.data.from_pydata([(-0.4, -0.4, 0), (0.4, -0.4, 0), (0.4, 0.4, 0), (-0.4, 0.4, 0)], [], [(0, 1, 2, 3)])
    xs = (-2.0, 0.5, 2.5)
    dots = _points(scene, "Dots", xs, (0.8, 0.0, 0.0))
    dots.location = (0.5, 0.0, 0.0)
    _instance_on_points(dots, square)
    instanced = render_exr(scene, tmp_path / "instanced.exr")

    bpy.data.objects.remove(dots)
    plain = add_plane(scene, "Plain", size=0.8, location=(0.5, 0.0, 0.0), velocity=(0.8, 0.0, 0.0))
    plain.data = bpy.data.meshes.new("Squares")
    plain.data.from_pydata([(x + dx, dy, 0.0) for x in xs for dx, dy in ((-0.4, -0.4), (0.4, -0.4), (0.4, 0.4), (-0.4, 0.4))],
                           [], [(4 * i, 4 * i + 1, 4 * i + 2, 4 * i + 3) for i in range(len(xs))])
    placed = render_exr(scene, tmp_path / "plain.exr")
    assert (placed["Doppler"] > 0).sum() > 50  # the squares are in view
    for name in ("Doppler", "Emission Time", "Combined"):
        np.testing.assert_allclose(instanced[name], placed[name], atol=1e-6, err_msg=name)


def test_text_parented_to_a_moving_body_contracts_about_the_bodys_pivot(scene, tmp_path):
    """A text label riding on a ship (the same velocity, parented) is part of the ship's assembly, as
    a mesh child is: it renders as the same letters converted to a mesh in its place."""
    scene.render.resolution_x, scene.render.resolution_y = 96, 24
    add_camera(scene, location=(-7.0, 0.0, 12.0))  # above where the label was when the light left it
    add_sun(scene)
    ship = add_plane(scene, "Ship", size=0.5, location=(0.5, 0.0, 0.0), velocity=(0.8, 0.0, 0.0))
    label = bpy.data.objects.new("Label", bpy.data.curves.new("Label", 'FONT'))
    label.data.body = "RF"
    scene.collection.objects.link(label)
    label.parent, label.location, label.restframe.velocity = ship, (3.0, -0.3, 0.0), (0.8, 0.0, 0.0)
    text = render_exr(scene, tmp_path / "text.exr")

    letters = bpy.data.meshes.new_from_object(label.evaluated_get(bpy.context.evaluated_depsgraph_get()))
    as_mesh = bpy.data.objects.new("Letters", letters)
    scene.collection.objects.link(as_mesh)
    as_mesh.parent, as_mesh.location, as_mesh.restframe.velocity = ship, (3.0, -0.3, 0.0), (0.8, 0.0, 0.0)
    bpy.data.objects.remove(label)
    mesh = render_exr(scene, tmp_path / "mesh.exr")
    assert (mesh["Doppler"] > 0).sum() > 40  # ship and letters in view
    for name in ("Doppler", "Emission Time", "Combined"):
        np.testing.assert_allclose(text[name], mesh[name], atol=1e-6, err_msg=name)


@pytest.mark.parametrize("name, value", [("Subsurface Weight", 0.5), ("Sheen Weight", 1.0), ("Anisotropic", 0.7),
                                         ("Specular Tint", (1.0, 0.2, 0.2, 1.0)), ("Thin Film Thickness", 300.0)])
def test_principled_inputs_not_modelled_are_warned_about_once(scene, name, value):
    add_camera(scene)
    plane = add_plane(scene)
    add_plane(scene, "Twin", location=(3.0, 0.0, 0.0)).data.materials.append(bpy.data.materials.new("Unused"))
    paint = principled("Velvet", **{name.replace(" ", "_"): value})
    plane.data.materials.append(paint)
    add_plane(scene, "Other", location=(-3.0, 0.0, 0.0)).data.materials.append(paint)
    _, _, warnings = export_now(scene)
    assert warnings == [f"Material 'Velvet': Principled {name} is not supported yet: rendered without"]


def test_a_linked_input_not_modelled_is_warned_about_and_the_defaults_are_not(scene):
    add_camera(scene)
    plain = principled("Plain")
    linked = principled("Linked")
    noise = linked.node_tree.nodes.new("ShaderNodeTexNoise")
    linked.node_tree.links.new(noise.outputs["Fac"], linked.node_tree.nodes["Principled BSDF"].inputs["Sheen Weight"])
    add_plane(scene, "A").data.materials.append(plain)
    add_plane(scene, "B", location=(3.0, 0.0, 0.0)).data.materials.append(linked)
    _, _, warnings = export_now(scene)
    assert warnings == ["Material 'Linked': Principled Sheen Weight is not supported yet: rendered without"]


def _add_lamp(scene, name, kind, location=(0.0, 0.0, 0.0), **data):
    """A lamp object ``name`` of ``kind`` at ``location``, its light's settings from ``data``."""
    lamp = bpy.data.objects.new(name, bpy.data.lights.new(name, kind))
    for setting, value in data.items():
        setattr(lamp.data, setting, value)
    lamp.location = location
    scene.collection.objects.link(lamp)
    return lamp


@pytest.mark.parametrize("kind", ['POINT', 'SPOT', 'AREA', 'SUN'])
def test_a_lamp_scaled_to_zero_renders_as_in_cycles(scene, tmp_path, kind):
    """A zero scale (a common way to switch a lamp off): a point lamp shines on as before (its
    axes do not matter, as in Cycles); the others give no light, as a spot or area lamp in Cycles,
    and say so, instead of a NaN direction."""
    add_camera(scene)
    add_plane(scene)
    lamp = _add_lamp(scene, "Lamp", kind, location=(0.0, 0.0, 3.0), energy=3.0 if kind == 'SUN' else 100.0)
    lit = render_exr(scene, tmp_path / "lit.exr")["Combined"]
    lamp.scale = (1.0, 1.0, 0.0)
    _, _, warnings = export_now(scene)
    flat = render_exr(scene, tmp_path / "flat.exr")["Combined"]
    assert lit[..., :3].mean() > 0.01
    if kind == 'POINT':
        assert warnings == [] and np.array_equal(flat, lit)
    else:
        assert warnings == ["Light 'Lamp': scaled to zero along an axis, it gives no light"]
        assert flat[..., :3].max() == 0.0


def _emission_strength(lamp, strength):
    """Set the Strength of the Emission node in the lamp's node tree (Cycles multiplies the lamp's by it)."""
    lamp.data.use_nodes = True
    next(n for n in lamp.data.node_tree.nodes if n.type == 'EMISSION').inputs["Strength"].default_value = strength


@pytest.mark.parametrize("kind, spoil, features", [
    ('SUN', lambda lamp: setattr(lamp.data, "use_shadow", False), ["lamp cast shadow off"]),
    ('POINT', lambda lamp: setattr(lamp, "visible_diffuse", False), ["lamp diffuse off"]),
    ('SPOT', lambda lamp: (setattr(lamp, "visible_glossy", False), setattr(lamp, "visible_transmission", False)),
     ["lamp glossy off", "lamp transmission off"]),
    ('AREA', lambda lamp: setattr(lamp.data, "spread", math.radians(60)), ["area lamp spread"]),
    ('POINT', lambda lamp: setattr(lamp.data, "energy", -100.0), ["lamp negative strength"]),
    ('SPOT', lambda lamp: _emission_strength(lamp, -2.0), ["lamp negative strength"]),  # (its node tree's)
])
def test_lamp_settings_the_render_leaves_out_are_warned_about(scene, kind, spoil, features):
    """Cycles honours these (a sun with Diffuse off lights a diffuse floor 0.018 where it lit it 0.19);
    the renderer does not yet, and says so, naming the lamps."""
    add_camera(scene)
    add_plane(scene)
    lamp = _add_lamp(scene, "Lamp", kind)
    other = _add_lamp(scene, "Other", kind, location=(1.0, 0.0, 3.0))
    assert export_now(scene)[2] == []
    spoil(lamp)
    spoil(other)
    assert export_now(scene)[2] == [f"Lamp, Other: {UNSUPPORTED[feature]}" for feature in features]


@pytest.mark.parametrize("data, message", [(None, "Rig: the scene camera is an empty object, not a camera"),
                                           ("FONT", "Rig: the scene camera is a text object, not a camera")])
def test_a_scene_camera_that_is_not_a_camera_is_named_in_plain_words(scene, data, message):
    rig = bpy.data.objects.new("Rig", None if data is None else bpy.data.curves.new("Rig", data))
    scene.collection.objects.link(rig)
    scene.camera = rig
    add_plane(scene)
    with pytest.raises(RuntimeError, match=message):
        render_exr(scene, "/nonexistent/never_written.exr")


@pytest.mark.parametrize("shape, size, size_y", [('SQUARE', 0.0, 1.0), ('DISK', 0.0, 1.0), ('RECTANGLE', 1.0, 0.0),
                                                 ('ELLIPSE', 0.0, 2.0)])
def test_an_area_lamp_of_size_zero_gives_no_light_as_in_cycles(scene, tmp_path, shape, size, size_y):
    """Cycles' area lamp of no area lights nothing (a 21x15 render of a plane under it: 0.0, where
    size 1 gives 0.23); it lit the plane as a point lamp here, without a word."""
    add_camera(scene)
    add_plane(scene)
    lamp = _add_lamp(scene, "Panel", 'AREA', location=(0.0, 0.0, 3.0), energy=100.0, shape=shape, size=size,
                     size_y=size_y)
    assert export_now(scene)[2] == ["Light 'Panel': an area lamp of size 0 gives no light (as in Cycles)"]
    assert render_exr(scene, tmp_path / "dark.exr")["Combined"][..., :3].max() == 0.0
    lamp.data.size = lamp.data.size_y = 1.0
    assert export_now(scene)[2] == []
    assert render_exr(scene, tmp_path / "lit.exr")["Combined"][..., :3].mean() > 0.01

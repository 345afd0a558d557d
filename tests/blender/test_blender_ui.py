"""Panel drawing, with a recording layout (there is no window in module mode).

Every property a panel shows must exist on the data it is drawn from, and the
texts the artist relies on (speed readouts, warnings) must appear.
"""

from types import SimpleNamespace

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane
from restframe_addon import ui


class Layout:
    """Stands in for bpy.types.UILayout: records labels and checks prop() names."""

    def __init__(self, record):
        self.record = record
        self.use_property_split = self.use_property_decorate = False
        self.active = self.enabled = True
        self.alert = False

    def _child(self, *args, **kwargs):
        return Layout(self.record)

    column = row = box = split = _child

    def prop(self, data, name, **kwargs):
        assert name in data.bl_rna.properties, f"{type(data).__name__} has no property {name!r}"
        index = kwargs.get("index", -1)
        if index >= 0:
            assert index < data.bl_rna.properties[name].array_length
        self.record.setdefault("props", []).append(name)

    def label(self, text="", icon='NONE', **kwargs):
        self.record.setdefault("labels", []).append(text)
        if icon == 'ERROR':
            self.record.setdefault("errors", []).append(text)

    def separator(self, **kwargs):
        pass


def draw(panel_class, context):
    record = {}
    panel = SimpleNamespace(layout=Layout(record), bl_space_type='PROPERTIES')
    assert panel_class.poll(context)
    panel_class.draw(panel, context)
    return record


def context_for(scene, obj=None):
    return SimpleNamespace(
        engine=scene.render.engine, scene=scene, view_layer=scene.view_layers[0], object=obj,
        light=obj.data if obj is not None and obj.type == 'LIGHT' else None)


def test_render_panels_draw_every_setting(scene):
    scene.restframe.integrator = 'PATH'  # its Light Paths panel shows the bounce limits and clamps
    context = context_for(scene)
    shown = set()
    for panel in (ui.RESTFRAME_RENDER_PT_relativity, ui.RESTFRAME_RENDER_PT_sampling, ui.RESTFRAME_RENDER_PT_light_paths,
                  ui.RESTFRAME_RENDER_PT_doppler, ui.RESTFRAME_RENDER_PT_motion_blur, ui.RESTFRAME_RENDER_PT_film,
                  ui.RESTFRAME_RENDER_PT_performance):
        shown |= set(draw(panel, context).get("props", []))
    settings = set(scene.restframe.bl_rna.properties.keys()) - {"rna_type", "name"}
    assert settings <= shown
    scene.frame_set(25)
    labels = draw(ui.RESTFRAME_RENDER_PT_relativity, context)["labels"]
    # 24 frames at 24 fps after the reference frame 1, with c = 10 units/s
    assert "Frame 25: t = 1 s, c\u00b7t = 10" in labels


def test_doppler_panel_flags_a_single_factor_level(scene):
    scene.restframe.doppler_mode, scene.restframe.doppler_levels = 'FACTOR', 1
    labels = draw(ui.RESTFRAME_RENDER_PT_doppler, context_for(scene)).get("labels", [])
    assert any("Levels must be 0 (continuous) or at least 2, not 1" in text for text in labels)
    scene.restframe.doppler_levels = 2
    assert not any("Levels" in text for text in draw(ui.RESTFRAME_RENDER_PT_doppler, context_for(scene)).get(
        "labels", []))


def test_every_toggle_of_the_passes_panel_adds_passes_the_render_delivers(scene):
    """Each switch the Passes panel shows turns on more passes of the render result (the ones the
    engine fills besides its own, which are always there): Blender's Depth, Normal and Object Index,
    and Cycles' two denoising passes (the names the compositor's Denoise node reads)."""
    from restframe_addon.engine import OBJECT_INDEX_PASS, list_render_passes

    layer = scene.view_layers[0]
    toggles = draw(ui.RESTFRAME_VIEWLAYER_PT_passes, context_for(scene))["props"]

    def owner(toggle):  # Blender's own pass switches are on the view layer, RESTframe's on its settings
        return layer if toggle in layer.bl_rna.properties else layer.restframe

    for toggle in toggles:
        setattr(owner(toggle), toggle, False)
    always = {name for name, _, _ in list_render_passes(scene, layer)}
    assert always == {"Combined", "Doppler", "Emission Time", "Object Time"}
    added = set()
    for toggle in toggles:
        setattr(owner(toggle), toggle, True)
        now = {name for name, _, _ in list_render_passes(scene, layer)}
        assert now - always - added, toggle
        added |= now - always
    assert added == {"Depth", "Normal", OBJECT_INDEX_PASS, "Denoising Normal", "Denoising Albedo"}


def test_light_paths_panel_shows_with_path_tracing(scene):
    """Cycles' Light Paths (total, diffuse, glossy, transmission bounces, clamps) for Path Tracing;
    Direct Light keeps its mirror/glass bounce limit in the Sampling panel."""
    context = context_for(scene)
    scene.restframe.integrator = 'DIRECT'
    assert not ui.RESTFRAME_RENDER_PT_light_paths.poll(context)
    assert "max_bounces" in draw(ui.RESTFRAME_RENDER_PT_sampling, context)["props"]
    scene.restframe.integrator = 'PATH'
    assert ui.RESTFRAME_RENDER_PT_light_paths.poll(context)
    assert "max_bounces" not in draw(ui.RESTFRAME_RENDER_PT_sampling, context)["props"]
    assert draw(ui.RESTFRAME_RENDER_PT_light_paths, context)["props"] == [
        "max_bounces", "diffuse_bounces", "glossy_bounces", "transmission_bounces", "clamp_direct", "clamp_indirect"]


def test_object_panel_shows_speed_and_warns_about_keyframed_location(scene):
    obj = add_plane(scene, velocity=(0.6, 0.0, 0.0))
    record = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))
    assert record["props"] == ["motion", "angular_velocity", "velocity", "lorentz_factor"]
    assert "Speed \u03b2 = 0.600000024 c" in record["labels"]  # the float32 value the user typed
    assert "Lorentz factor \u03b3 = 1.25000003" in record["labels"]
    assert "errors" not in record

    obj.keyframe_insert("location", frame=1)
    record = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))
    assert any("keyframed" in text for text in record["errors"])
    assert "Set Motion to Animation to follow the keyframed path" in record["labels"]

    obj.restframe.motion = 'ANIMATION'  # the keyframed path is the world line: no warning, no velocity
    record = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))
    assert record["props"] == ["motion"] and "errors" not in record
    assert any("keyframed location" in text for text in record["labels"])
    obj.restframe.motion = 'CONSTANT'

    obj.restframe.velocity = (1.0, 0.0, 0.0)
    obj.restframe.lorentz_factor = 1e7
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))["labels"]
    assert "Speed \u03b2 = 1 \u2212 5e-15 c" in labels

    obj.restframe.lorentz_factor = 0.0
    obj.restframe.velocity = (1.0, 0.5, 0.0)
    errors = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))["errors"]
    assert any("not below the speed of light" in text for text in errors)


def test_object_panel_on_a_child_of_a_moving_parent(scene):
    parent = add_plane(scene, "Ship", velocity=(0.5, 0.0, 0.0))
    child = add_plane(scene, "Mast", velocity=(0.5, 0.0, 0.0))
    child.parent = parent
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, child))["labels"]
    assert any("'Ship'" in text for text in labels)


def test_object_panel_of_a_camera_riding_with_its_parent(scene):
    ship = add_plane(scene, "Ship", velocity=(0.5, 0.0, 0.0))
    camera = add_camera(scene)
    camera.parent = ship
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, camera))["labels"]
    assert any("Rides with its parent 'Ship'" in text for text in labels)
    camera.restframe.velocity = (0.0, 0.2, 0.0)  # motion of its own: its own assembly
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, camera))["labels"]
    assert not any("'Ship'" in text for text in labels)
    ship.restframe.motion = camera.restframe.motion = 'ANIMATION'  # the same Motion: the ship's world line
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, camera))["labels"]
    assert any("World line: that of its parent 'Ship'" in text for text in labels)


@pytest.mark.parametrize("kind", ['POINT', 'SPOT', 'SUN', 'AREA'])
def test_light_panel(scene, kind):
    light = bpy.data.objects.new("L", bpy.data.lights.new("L", kind))
    scene.collection.objects.link(light)
    props = draw(ui.RESTFRAME_LIGHT_PT_light, context_for(scene, light))["props"]
    assert {"type", "color", "energy"} <= set(props)


def test_camera_object_panel(scene):
    camera = add_camera(scene)
    camera.restframe.velocity = (0.0, 0.0, -0.5)
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, camera))["labels"]
    assert any("Moving observer" in text for text in labels)


def test_panels_hide_for_other_engines(scene):
    scene.render.engine = 'CYCLES'
    context = context_for(scene, add_plane(scene))
    assert not ui.RESTFRAME_RENDER_PT_relativity.poll(context)
    assert not ui.RESTFRAME_OBJECT_PT_motion.poll(context)


def test_velocity_arrows_geometry(scene):
    from restframe_addon.overlay import arrow_segments

    scene.restframe.light_speed = 10.0
    add_plane(scene, "Still")
    ship = add_plane(scene, "Ship", location=(1.0, 2.0, 3.0), velocity=(0.0, 0.6, 0.0))
    fast = add_plane(scene, "Fast", velocity=(0.0, 0.0, -1.0))
    fast.restframe.lorentz_factor = 1e9  # beta = 1 - 5e-19: the arrow is c x 1 s long
    add_plane(scene, "Broken", velocity=(2.0, 0.0, 0.0))  # invalid: no arrow
    scene.view_layers[0].update()  # matrix_world, as the viewport has it
    segments = arrow_segments(scene, scene.view_layers[0])
    assert segments.shape == (6, 2, 3)
    np.testing.assert_allclose(segments[0], [(1.0, 2.0, 3.0), (1.0, 8.0, 3.0)], atol=1e-5)  # 0.6 c x 1 s
    np.testing.assert_allclose(segments[3], [(0.0, 0.0, 0.0), (0.0, 0.0, -10.0)], atol=1e-5)
    head = segments[1:3, 1] - segments[1:3, 0]
    assert np.all(head[:, 1] < 0)  # head strokes point back along the shaft
    ship.hide_set(True)
    assert arrow_segments(scene, scene.view_layers[0]).shape == (3, 2, 3)


def test_velocity_arrows_are_drawn_from_the_origin_only_for_restframe(scene, monkeypatch):
    """The viewport's draw handler (no GPU in module mode: a recording stand-in for ``gpu``) draws one
    arrow per moving object -- the shaft from its origin, 0.5 c x 1 s = 5 units (c = 10) along its
    velocity, and two head strokes -- and nothing when the arrows are off or another engine renders."""
    import sys
    import types

    from restframe_addon import overlay

    drawn = []

    class Shader:
        def uniform_float(self, name, value):
            pass

    class Batch:
        def __init__(self, points):
            self.points = points

        def draw(self, shader):
            drawn.append(self.points)

    fake_gpu = types.SimpleNamespace(
        shader=types.SimpleNamespace(from_builtin=lambda name: Shader()),
        state=types.SimpleNamespace(viewport_get=lambda: (0, 0, 640, 480), blend_set=lambda mode: None))
    monkeypatch.setitem(sys.modules, "gpu", fake_gpu)
    monkeypatch.setitem(sys.modules, "gpu_extras.batch", types.SimpleNamespace(
        batch_for_shader=lambda shader, kind, content: Batch(np.array(content["pos"]).reshape(-1, 2, 3))))

    add_plane(scene, "Still")
    add_plane(scene, "Ship", location=(1.0, 2.0, 3.0), velocity=(0.5, 0.0, 0.0))
    scene.view_layers[0].update()
    overlay.draw_arrows()
    (segments,) = drawn
    assert segments.shape == (3, 2, 3)
    np.testing.assert_allclose(segments[0], [(1.0, 2.0, 3.0), (6.0, 2.0, 3.0)], atol=1e-5)
    np.testing.assert_allclose(segments[1:, 0], [(6.0, 2.0, 3.0)] * 2, atol=1e-5)  # the head at the tip
    assert np.all(segments[1:, 1, 0] < 6.0)  # pointing back along the shaft
    scene.restframe.show_velocity = False
    overlay.draw_arrows()
    scene.restframe.show_velocity = True
    scene.render.engine = 'CYCLES'
    overlay.draw_arrows()
    assert len(drawn) == 1

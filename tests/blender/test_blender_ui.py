"""Panel drawing, with a recording layout (there is no window in module mode).

Every property a panel shows must exist on the data it is drawn from, and the
texts the artist relies on (speed readouts, warnings) must appear.
"""

from types import SimpleNamespace

import bpy
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
    context = context_for(scene)
    shown = set()
    for panel in (ui.RESTFRAME_RENDER_PT_relativity, ui.RESTFRAME_RENDER_PT_sampling, ui.RESTFRAME_RENDER_PT_doppler,
                  ui.RESTFRAME_RENDER_PT_film, ui.RESTFRAME_RENDER_PT_performance):
        shown |= set(draw(panel, context).get("props", []))
    settings = set(scene.restframe.bl_rna.properties.keys()) - {"rna_type", "name"}
    assert settings <= shown
    scene.frame_set(25)
    labels = draw(ui.RESTFRAME_RENDER_PT_relativity, context)["labels"]
    # 24 frames at 24 fps after the reference frame 1, with c = 10 units/s
    assert "Frame 25: t = 1 s, c\u00b7t = 10" in labels


def test_passes_panel(scene):
    props = draw(ui.RESTFRAME_VIEWLAYER_PT_passes, context_for(scene))["props"]
    assert props == ["use_pass_z", "use_pass_normal", "use_pass_object_index"]


def test_object_panel_shows_speed_and_warns_about_keyframed_location(scene):
    obj = add_plane(scene, velocity=(0.6, 0.0, 0.0))
    record = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))
    assert record["props"] == ["velocity", "lorentz_factor"]
    assert "Speed \u03b2 = 0.600000024 c" in record["labels"]  # the float32 value the user typed
    assert "Lorentz factor \u03b3 = 1.25000003" in record["labels"]
    assert "errors" not in record

    obj.keyframe_insert("location", frame=1)
    record = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, obj))
    assert any("keyframed" in text for text in record["errors"])

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

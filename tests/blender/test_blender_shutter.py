"""Motion blur from Blender's Motion Blur panel matches Cycles at rest with c very large: the streak
of a keyframed emitter over the shutter, and the slant a rolling shutter gives a moving bar."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, export_now
from measures import streak_ends
from test_blender_dof import black_world, emissive, render

WIDTH, HEIGHT = 128, 24
LENS_MM, SENSOR_MM = 50.0, 36.0
FOCAL_PIXELS = LENS_MM / SENSOR_MM * WIDTH
DEPTH = 5.0


def moving_emitter(scene, make, speed):
    """``make`` adds an emissive object at DEPTH ahead of the camera; it is keyed to move along x
    at ``speed`` scene units per frame through x = 0 at frame 10 (linear keys), Motion = Animation."""
    scene.render.resolution_x, scene.render.resolution_y = WIDTH, HEIGHT
    scene.restframe.light_speed = 1e9  # c very large: Cycles' world
    black_world(scene)
    add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0), lens=LENS_MM,
               sensor_width=SENSOR_MM, sensor_fit='HORIZONTAL', clip_start=0.01)
    obj = make()
    obj.data.materials.append(emissive("Glow"))
    obj.restframe.motion = 'ANIMATION'
    for frame in (5, 15):
        obj.location = ((frame - 10) * speed, DEPTH, 0.0)
        obj.keyframe_insert("location", frame=frame)
    action = obj.animation_data.action
    curves = action.fcurves if hasattr(action, "fcurves") else action.layers[0].strips[0].channelbag(
        action.slots[0]).fcurves
    for curve in curves:
        for key in curve.keyframe_points:
            key.interpolation = 'LINEAR'
    scene.frame_set(10)
    scene.render.use_motion_blur = True
    return obj


@pytest.mark.parametrize("position", ['CENTER', 'START'])
def test_streak_of_a_keyframed_emitter_matches_cycles(scene, tmp_path, position):
    """1.5 frames of shutter, the emitter moving 0.5 units a frame: a streak of 0.75 units at 5 m
    (26.7 px), centred on the frame's position or starting there, as long as Cycles' to 2%."""
    def sphere():
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.03, segments=24, ring_count=12)
        return bpy.context.object

    moving_emitter(scene, sphere, speed=0.5)
    scene.render.motion_blur_shutter = 1.5
    scene.render.motion_blur_position = position
    ends = {engine: streak_ends(render(scene, tmp_path, engine, samples=512).sum(axis=0))
            for engine in ('RESTFRAME', 'CYCLES')}
    opens = {'CENTER': -0.75, 'START': 0.0}[position]
    expected = WIDTH / 2 + np.array([opens, opens + 1.5]) * 0.5 / DEPTH * FOCAL_PIXELS
    print(f"streak ends ({position}): RESTframe {ends['RESTFRAME']}, Cycles {ends['CYCLES']}, expected {expected} px")
    length = {engine: e[1] - e[0] for engine, e in ends.items()}
    assert length["RESTFRAME"] == pytest.approx(length["CYCLES"], rel=0.02)
    assert length["RESTFRAME"] == pytest.approx(expected[1] - expected[0], rel=0.02)
    np.testing.assert_allclose(ends["RESTFRAME"], ends["CYCLES"], atol=0.5)


def test_rolling_shutter_slants_a_moving_bar_as_cycles(scene, tmp_path):
    """Rows read out from the top over one frame of shutter (duration 0: each row at one instant): a
    vertical bar moving along x leans by its motion over the frame from the top row to the bottom
    one, as in Cycles."""
    def bar():
        bpy.ops.mesh.primitive_cube_add(size=1.0)
        obj = bpy.context.object
        obj.scale = (0.02, 0.02, 2.0)
        return obj

    moving_emitter(scene, bar, speed=0.5)
    scene.render.motion_blur_shutter = 1.0
    scene.restframe.rolling_shutter_type = scene.cycles.rolling_shutter_type = 'TOP'
    scene.restframe.rolling_shutter_duration = scene.cycles.rolling_shutter_duration = 0.0
    slopes = {}
    for engine in ('RESTFRAME', 'CYCLES'):
        image = render(scene, tmp_path, engine, samples=64)
        x = np.arange(WIDTH) + 0.5
        centres = (image * x).sum(axis=1) / image.sum(axis=1)
        slopes[engine] = np.polyfit(np.arange(HEIGHT) + 0.5, centres, 1)[0]
    # row y is read at 1 - y / H of the shutter: up one row = 1/H frame earlier = 0.5 / H units to the left
    expected = -0.5 / HEIGHT / DEPTH * FOCAL_PIXELS
    print(f"bar slope (px per row): RESTframe {slopes['RESTFRAME']:.4f}, Cycles {slopes['CYCLES']:.4f}, "
          f"closed form {expected:.4f}")
    assert slopes["RESTFRAME"] == pytest.approx(slopes["CYCLES"], rel=0.02)
    assert slopes["RESTFRAME"] == pytest.approx(expected, rel=0.02)


def test_shutter_settings_export_on_the_camera_clock(scene):
    add_camera(scene)
    scene.render.fps, scene.render.fps_base = 25, 1.0
    out, _, _ = export_now(scene)
    assert out.camera.shutter_interval is None  # motion blur off: an instant
    scene.render.use_motion_blur = True
    scene.render.motion_blur_shutter = 0.5
    scene.render.motion_blur_position = 'END'
    scene.restframe.rolling_shutter_type = 'TOP'
    scene.restframe.rolling_shutter_duration = 0.3
    out, _, _ = export_now(scene)
    assert out.camera.shutter_interval == pytest.approx((-0.02, 0.0))
    assert out.camera.shutter_curve is None  # Blender's default curve is flat
    assert (out.camera.rolling_shutter_type, out.camera.rolling_shutter_duration) == ('TOP', pytest.approx(0.3))
    bpy.ops.render.shutter_curve_preset(shape='SHARP')
    scene.update_tag()  # the operator does not tag the scene for the depsgraph's copy
    out, _, _ = export_now(scene)
    curve = out.camera.shutter_curve
    assert len(curve) == 256 and curve[0] == pytest.approx(0.0, abs=1e-3) and curve[128] == pytest.approx(1.0, abs=1e-2)


def test_shutter_curve_shapes_the_streak_as_in_cycles(scene, tmp_path):
    """Blender's Sharp shutter curve (open mostly mid-shutter): the streak's light is concentrated at
    its middle: the spread of its column profile (standard deviation) is that of the curve's density
    times the streak's length (to 2%), as in Cycles (to 5%: Cycles' 256-entry inverse table gives
    the Sharp curve a spread 2.6% narrower than its density), well below the flat shutter's."""
    def sphere():
        bpy.ops.mesh.primitive_uv_sphere_add(radius=0.02, segments=24, ring_count=12)
        return bpy.context.object

    moving_emitter(scene, sphere, speed=0.5)
    scene.render.motion_blur_shutter = 2.0
    bpy.ops.render.shutter_curve_preset(shape='SHARP')
    scene.update_tag()
    spread = {}
    for engine in ('RESTFRAME', 'CYCLES'):
        profile = render(scene, tmp_path, engine, samples=512).sum(axis=0)
        x = np.arange(WIDTH) + 0.5
        mean = (profile * x).sum() / profile.sum()
        spread[engine] = math.sqrt((profile * (x - mean) ** 2).sum() / profile.sum())
    length = 2.0 * 0.5 / DEPTH * FOCAL_PIXELS
    curve = export_now(scene)[0].camera.shutter_curve
    fine = np.linspace(0.0, 1.0, 100_001)
    density = np.interp(fine, np.linspace(0.0, 1.0, len(curve)), curve)
    density /= density.sum()
    mean = (density * fine).sum()
    expected = math.sqrt((density * (fine - mean) ** 2).sum() * length**2 + 1 / 12)  # and the pixel's width
    print(f"streak spread (px): RESTframe {spread['RESTFRAME']:.3f}, Cycles {spread['CYCLES']:.3f}, "
          f"from the curve {expected:.3f}, flat shutter {length / math.sqrt(12):.3f}")
    assert spread["RESTFRAME"] == pytest.approx(expected, rel=0.02)
    assert spread["RESTFRAME"] == pytest.approx(spread["CYCLES"], rel=0.05)
    assert spread["RESTFRAME"] < 0.6 * length / math.sqrt(12)


def test_motion_blur_panels_draw_blenders_settings_and_ours(scene):
    """The Motion Blur panel shows Blender's shutter and position and RESTframe's rolling shutter;
    its Shutter Curve subpanel Blender's curve and presets."""
    from types import SimpleNamespace

    import test_blender_ui
    from restframe_addon import ui

    class Layout(test_blender_ui.Layout):
        def _child(self, *args, **kwargs):
            return Layout(self.record)

        column = row = box = split = _child

        def template_curve_mapping(self, data, name, **kwargs):
            self.prop(data, name)

        def operator(self, name, **kwargs):
            self.record.setdefault("operators", []).append(name)
            return SimpleNamespace()

    def draw(panel_class):
        record = {}
        panel = SimpleNamespace(layout=Layout(record), bl_space_type='PROPERTIES')
        assert panel_class.poll(test_blender_ui.context_for(scene))
        panel_class.draw(panel, test_blender_ui.context_for(scene))
        return record

    shown = draw(ui.RESTFRAME_RENDER_PT_motion_blur)
    assert {"motion_blur_position", "motion_blur_shutter", "rolling_shutter_type", "rolling_shutter_duration"} <= set(shown["props"])
    assert any("camera's own clock" in text for text in shown["labels"])
    curve = draw(ui.RESTFRAME_RENDER_PT_motion_blur_curve)
    assert curve["props"] == ["motion_blur_shutter_curve"] and len(curve["operators"]) == 6

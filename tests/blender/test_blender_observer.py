"""Motion = Animation on cameras and lamps, Blender side: a camera keyed on a hyperbolic world line
observes in its momentary rest frame and reads the analytic proper time (panel property and the
render's metadata); a lamp keyed to flash and to move lights the floor from its retarded events."""

import dataclasses
import math

import bpy
import numpy as np
import OpenEXR
import pytest

from blender_helpers import add_camera, add_plane, export_now, render_exr, render_eyes, render_rgba
from restframe_addon import engine, motion_query
from restframe_addon.core.prepared import prepare

FPS = 24
C = 10.0  # scene units per second
ACCEL = 4.0  # proper acceleration, scene units / s^2: a / c = 0.4 per second


def hyperbolic_x(t):
    """Uniform proper acceleration from rest at t = 0 (frame 1), along x (rest before)."""
    t = max(t, 0.0)
    return C * C / ACCEL * (math.sqrt(1.0 + (ACCEL * t / C) ** 2) - 1.0)


def key_every_frame(obj, position_at, frames, interpolation='BEZIER'):
    """Keys on every frame: Blender's automatic Bezier handles make the path the hyperbola to
    ~1e-7 of its proper time (linear keys: ~1e-5)."""
    for frame in frames:
        obj.location = position_at((frame - 1) / FPS)
        obj.keyframe_insert("location", frame=frame)
    animation = obj.animation_data
    for fc in motion_query.fcurves(animation.action, getattr(animation, "action_slot", None)):
        fc.extrapolation = 'LINEAR'
        for point in fc.keyframe_points:
            point.interpolation = interpolation


def rocket_scene(scene, frame):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.light_speed = C
    scene.restframe.reference_frame = 1
    scene.frame_start = 1
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, math.radians(-90)))
    key_every_frame(camera, lambda t: (hyperbolic_x(t), 0.0, 0.0), range(-30, 120))
    camera.restframe.motion = 'ANIMATION'
    scene.frame_set(frame)
    return camera


@pytest.mark.parametrize("frame", [25, 73])
def test_keyed_hyperbolic_camera_reads_the_analytic_proper_time_and_observes_at_its_momentary_velocity(
        scene, frame):
    camera = rocket_scene(scene, frame)
    t = (frame - 1) / FPS
    analytic = C / ACCEL * math.asinh(ACCEL * t / C)
    assert camera.restframe.proper_time == pytest.approx(analytic, rel=1e-5)
    seconds, beta = motion_query.clock(camera, scene)
    u = ACCEL * t / C
    # the keyed Bezier path's slope at a key is the hyperbola's to second order in the key spacing
    assert beta[0] == pytest.approx(u / math.sqrt(1.0 + u * u), rel=1e-4)  # 0.371 c at frame 25, 0.768 c at 73
    out, settings, _ = export_now(scene)
    assert out.camera.trajectory is not None
    prepared = prepare(out, settings)
    camera_frame = prepared.frames.frames[prepared.frames.camera]
    assert camera_frame.velocity.beta[0] == pytest.approx(beta[0], rel=1e-6)
    # the render's stamp and the panel read the same clock
    stamp = engine.observer_stamp(out)[engine.STAMP_PROPER_TIME]
    assert float(stamp.split()[0]) == pytest.approx(analytic, rel=1e-5)


def test_constant_velocity_camera_and_lamp_clocks_run_slow_by_gamma(scene):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    camera = add_camera(scene)
    camera.restframe.velocity = (0.6, 0.0, 0.0)
    scene.frame_set(49)  # 2 s
    assert motion_query.clock(camera, scene)[0] == pytest.approx(2.0 * 0.8, rel=1e-7)  # beta 0.6 as a float32
    assert camera.restframe.proper_time == pytest.approx(2.0 * 0.8, rel=1e-7)  # a float32 property
    camera.restframe.velocity = (0.0, 0.0, 0.0)
    assert camera.restframe.proper_time == pytest.approx(2.0, rel=1e-7)


def exr_header(path):
    with OpenEXR.File(str(path)) as exr:
        return {k: v for part in exr.parts for k, v in part.header.items()}


def test_the_render_metadata_stamps_observer_proper_time_in_exr_and_png(scene, tmp_path):
    rocket_scene(scene, 49)
    add_plane(scene, size=4.0, location=(40.0, 0.0, 0.0))
    expected = C / ACCEL * math.asinh(ACCEL * 2.0 / C)
    render_exr(scene, tmp_path / "frame.exr")
    header = exr_header(tmp_path / "frame.exr")
    stamped = [v for k, v in header.items() if engine.STAMP_PROPER_TIME in k]
    assert stamped, sorted(header)
    value = stamped[0].decode() if isinstance(stamped[0], bytes) else str(stamped[0])
    assert float(value.split()[0]) == pytest.approx(expected, rel=1e-5)
    settings = scene.render.image_settings
    if hasattr(settings, "media_type"):  # Blender 5.0
        settings.media_type = 'IMAGE'
    settings.file_format = 'PNG'
    scene.render.filepath = str(tmp_path / "frame.png")
    bpy.ops.render.render(write_still=True)
    png = (tmp_path / "frame.png").read_bytes()  # a tEXt chunk: key, NUL, value
    key = engine.STAMP_PROPER_TIME.encode() + b"\0"
    assert key in png
    value = png[png.index(key) + len(key):].split(b" s")[0]
    assert float(value) == pytest.approx(expected, rel=1e-5)


def add_point_lamp(scene, location, watts=0.0):
    light = bpy.data.lights.new("Flash", 'POINT')
    light.energy = watts
    light.shadow_soft_size = 0.0
    obj = bpy.data.objects.new("Flash", light)
    obj.location = location
    scene.collection.objects.link(obj)
    return obj


def key_pulse(light, frames, watts):
    """Energy keyed as a pulse on the lamp's clock: on from frames[0] to frames[1] (Constant keys)."""
    for frame, value in ((frames[0] - 1, 0.0), (frames[0], watts), (frames[1], 0.0)):
        light.energy = value
        light.keyframe_insert("energy", frame=frame)
    animation = light.animation_data
    for fc in motion_query.fcurves(animation.action, getattr(animation, "action_slot", None)):
        for point in fc.keyframe_points:
            point.interpolation = 'CONSTANT'


@pytest.mark.parametrize("speed", [0.0, 0.6])
def test_a_keyed_flash_exports_on_the_lamps_clock_and_its_world_line(scene, speed):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    add_camera(scene, location=(0.0, -10.0, 8.0))
    lamp = add_point_lamp(scene, (0.0, 0.0, 2.0))
    key_pulse(lamp.data, (13, 25), 3000.0)  # on from 0.5 s to 1 s of the lamp's clock
    if speed:
        key_every_frame(lamp, lambda t: (speed * C * t, 0.0, 2.0), range(-60, 120), 'LINEAR')
        lamp.restframe.motion = 'ANIMATION'
    scene.frame_set(60)
    out, _, warnings = export_now(scene)
    (light,) = out.lights
    seconds, watts = light.power_curve
    on = seconds[watts > 0]
    assert on.min() == pytest.approx(0.5, abs=1e-5) and on.max() == pytest.approx(1.0, abs=1e-4)
    if speed:
        _, beta = light.trajectory.state(np.array([out.tau_obs]))
        assert beta[0][0] == pytest.approx(speed, rel=1e-9)
        assert motion_query.clock(lamp, scene)[0] == pytest.approx((59 / FPS) * math.sqrt(1 - speed**2), rel=1e-9)
    else:
        assert light.trajectory is None
    assert not warnings


def test_flash_seen_in_blender_lights_the_floor_only_between_the_ellipses(scene, tmp_path):
    """The whole path: keyed energy pulse on a lamp moving at 0.6c (keyed location) above a floor,
    rendered by the engine; every floor pixel whose light left inside the pulse (by a pixel's
    margin) is lit, every one outside is dark."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    scene.restframe.light_speed = C
    scene.render.resolution_x = scene.render.resolution_y = 48
    scene.world = None
    camera_position = np.array([0.0, -10.0, 8.0])
    add_camera(scene, location=tuple(camera_position), rotation=(math.radians(45), 0.0, 0.0))
    add_plane(scene, size=60.0)
    lamp = add_point_lamp(scene, (0.0, 0.0, 2.0))
    key_pulse(lamp.data, (1, 13), 30000.0)  # on for 0.5 s of the lamp's clock from its zero
    start, beta = np.array([-3.0, 0.0, 2.0]), np.array([0.6, 0.0, 0.0])
    key_every_frame(lamp, lambda t: tuple(start + beta * C * t), range(-60, 120), 'LINEAR')
    lamp.restframe.motion = 'ANIMATION'
    scene.frame_set(73)  # 3 s: light travel of about 30 units
    image = render_exr(scene, tmp_path / "flash.exr")["Combined"][..., 0]
    # each pixel centre's floor point, from Blender's own camera
    out, settings, _ = export_now(scene)
    rays = prepare(out, settings).centre_rays((0, 0, 48, 48))
    d = rays[2]
    s = -camera_position[2] / d[:, 2]
    x = (camera_position + s[:, None] * d).reshape(48, 48, 3)
    on_floor = ((s > 0) & np.all(np.abs((camera_position + s[:, None] * d)[:, :2]) < 29.0, axis=1)).reshape(48, 48)
    t_x = C * 3.0 - np.linalg.norm(x - camera_position, axis=-1)  # c t when the light reaches the floor
    r = x - start
    b2 = beta @ beta
    half_b = -(t_x - r @ beta * C / C)
    emitted = (-half_b - np.sqrt(half_b**2 - (1 - b2) * (t_x**2 - np.einsum("...i,...i", r, r)))) / (1 - b2)
    # the pulse in world c t: its clock runs 0.8 as fast
    pulse = C * 0.5 / math.sqrt(1 - b2)
    step = np.hypot(*np.gradient(emitted))
    inside = on_floor & (emitted > step) & (emitted < pulse - step)
    outside = on_floor & ((emitted < -step) | (emitted > pulse + step))
    lit = image > 1e-6
    assert inside.sum() > 20 and outside.sum() > 300
    assert lit[inside].all() and not lit[outside].any()


def test_the_motion_panel_shows_the_clock_and_speed_of_cameras_and_lamps(scene):
    from test_blender_ui import context_for, draw

    from restframe_addon import ui

    camera = rocket_scene(scene, 25)
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, camera))["labels"]
    expected = C / ACCEL * math.asinh(ACCEL / C)
    assert any(text.startswith("Proper time ") and abs(float(text.split()[2]) - expected) < 1e-6
               for text in labels), labels
    assert any("Speed" in text and "0.371" in text for text in labels), labels
    assert any("momentary rest frame" in text for text in labels)
    lamp = add_point_lamp(scene, (0.0, 0.0, 2.0), watts=100.0)
    lamp.restframe.velocity = (0.6, 0.0, 0.0)
    labels = draw(ui.RESTFRAME_OBJECT_PT_motion, context_for(scene, lamp))["labels"]
    assert any(text.startswith("Proper time ") and abs(float(text.split()[2]) - 0.8) < 1e-6 for text in labels)


def test_keyed_node_emission_strength_and_colour_enter_the_lamp_curves(scene):
    """A light node tree's Emission strength, keyed, multiplies the lamp's power on its clock; its
    colour tints the keyed colour (as Cycles multiplies both into the lamp)."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    add_camera(scene)
    lamp = add_point_lamp(scene, (0.0, 0.0, 2.0), watts=100.0)
    lamp.data.use_nodes = True
    emission = next(n for n in lamp.data.node_tree.nodes if n.type == 'EMISSION')
    emission.inputs["Color"].default_value = (1.0, 0.5, 0.25, 1.0)
    strength = emission.inputs["Strength"]
    for frame, value in ((1, 0.0), (25, 3.0)):
        strength.default_value = value
        strength.keyframe_insert("default_value", frame=frame)
    for frame, value in ((1, (1.0, 1.0, 1.0)), (25, (0.0, 1.0, 0.0))):
        lamp.data.color = value
        lamp.data.keyframe_insert("color", frame=frame)
    for animation in (lamp.data.node_tree.animation_data, lamp.data.animation_data):
        for fc in motion_query.fcurves(animation.action, getattr(animation, "action_slot", None)):
            for point in fc.keyframe_points:
                point.interpolation = 'LINEAR'
    scene.frame_set(60)
    out, _, _ = export_now(scene)
    (light,) = out.lights
    seconds, watts = light.power_curve
    assert np.interp(0.5, seconds, watts) == pytest.approx(100.0 * 1.5)  # frame 13: halfway up
    assert np.interp(1.0, seconds, watts) == pytest.approx(300.0)
    seconds, colours = light.color_curve
    np.testing.assert_allclose([np.interp(0.5, seconds, colours[:, i]) for i in range(3)], [0.5, 0.5, 0.125],
                               atol=1e-6)


def stereo_rig_camera(scene, motion='ANIMATION'):
    """A stereo camera riding with a rig, looking along +y with its eyes along x, the direction of
    the motion, at a row of lit cards: the rig accelerating (Motion = Animation, the hyperbolic
    rocket's keys; two seconds into the acceleration, 0.63 c) or at 0.63 c ('CONSTANT')."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.light_speed = C
    scene.restframe.reference_frame = 1
    scene.frame_start = 1
    scene.render.resolution_x, scene.render.resolution_y = 32, 16
    scene.restframe.samples = 2
    rig = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(rig)
    rig.restframe.motion = motion
    if motion == 'ANIMATION':
        key_every_frame(rig, lambda t: (hyperbolic_x(t), 0.0, 0.0), range(-30, 120))
    else:  # where the accelerating rig is at frame 49, two seconds after the reference frame
        rig.restframe.velocity = (0.63, 0.0, 0.0)
        rig.location = (hyperbolic_x(2.0) - 0.63 * C * 2.0, 0.0, 0.0)
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0))
    camera.parent = rig  # no motion of its own: it rides with the rig
    camera.data.stereo.interocular_distance = 1.0
    camera.data.stereo.convergence_mode, camera.data.stereo.pivot = 'PARALLEL', 'CENTER'  # eyes at x -+0.5
    for index in range(7):  # behind the camera's x: aberration turns them into its view
        card = add_plane(scene, f"Card{index}", size=1.0, location=(-2.0 + 1.5 * index, 6.0, 0.0))
        card.rotation_euler = (math.radians(90), 0.0, 0.0)
    add_point_lamp(scene, (2.5, 3.0, 2.0), watts=3000.0)
    scene.frame_set(49)
    return camera


@pytest.mark.parametrize("motion", ['ANIMATION', 'CONSTANT'])
@pytest.mark.parametrize("parallelism", ['THREADS', 'PROCESSES'])
def test_each_stereo_eye_of_a_moving_camera_observes_from_its_own_world_line(scene, tmp_path, monkeypatch,
                                                                             parallelism, motion):
    """Stereoscopy on a moving camera: each eye is a point of the camera's (Born-rigid) assembly on
    a world line of its own (docs/physics.md#observer), so it sees what the camera moved to the
    eye's place renders alone: the same observation event, momentary rest frame (accelerating:
    0.632 c and 0.617 c, the eyes lie along the acceleration) and image, whether the second eye's
    rest frames are shared with the first's (threads) or built again in each worker process."""
    from restframe_addon import export
    from restframe_addon.core.observer import camera_velocity

    eyes = []
    view_camera = export.view_camera
    monkeypatch.setattr(export, "view_camera", lambda *args: eyes.append(view_camera(*args)) or eyes[-1])
    camera = stereo_rig_camera(scene, motion)
    scene.restframe.parallelism = parallelism
    scene.render.use_multiview = True
    stereo = render_eyes(scene, tmp_path / "stereo")
    assert len(eyes) == 2
    assert all((image[..., 0] > 0.01).sum() > 20 for image in stereo)  # cards in view
    assert not np.allclose(stereo[0], stereo[1], rtol=1e-3)  # the eyes see different images
    left_beta, right_beta = (camera_velocity(eye, export_now(scene)[0].tau_obs).beta[0] for eye in eyes)
    if motion == 'ANIMATION':
        assert left_beta - right_beta > 0.01  # the eye ahead accelerates less (Born rigidity)
    else:
        assert left_beta == right_beta == pytest.approx(0.63)

    scene.render.use_multiview = False
    for side, seen, seen_image in zip((-0.5, 0.5), eyes, stereo):
        camera.location = (side, 0.0, 0.0)
        out, settings, _ = export_now(scene)
        alone = prepare(out, settings)
        view = prepare(dataclasses.replace(out, camera=seen), settings)
        np.testing.assert_allclose(view.scene.camera.matrix, alone.scene.camera.matrix, atol=1e-6)
        np.testing.assert_allclose(view.frames.frames[view.frames.camera].velocity.beta,
                                   alone.frames.frames[alone.frames.camera].velocity.beta, rtol=1e-9)
        np.testing.assert_allclose([view.camera_tau, *view.camera_rays.position],  # the observation event in C
                                   [alone.camera_tau, *alone.camera_rays.position], atol=1e-6)
        np.testing.assert_allclose(seen_image, render_rgba(scene, tmp_path / f"alone{side}.exr"), rtol=1e-5,
                                   atol=1e-7)

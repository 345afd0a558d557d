"""Motion beyond constant velocity, Blender side: Motion = Animation, angular velocity, Object Time."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, add_plane, add_sun, render_exr, export_now
from restframe_addon import export, motion_query
from restframe_addon.export.motion import SUBFRAMES

FPS = 24


def key_linear_path(obj, start, beta, c, frames=(1, 25)):
    """Keys on the location for a straight path at beta (units of c), linear and extrapolated."""
    for frame in frames:
        t = (frame - frames[0]) / FPS
        obj.location = tuple(np.asarray(start) + np.asarray(beta) * c * t)
        obj.keyframe_insert("location", frame=frame)
    action = obj.animation_data.action
    fcurves = motion_query.fcurves(action, getattr(obj.animation_data, "action_slot", None))
    for fc in fcurves:
        fc.extrapolation = 'LINEAR'
        for point in fc.keyframe_points:
            point.interpolation = 'LINEAR'


def test_keyframed_linear_motion_renders_like_the_constant_velocity(scene, tmp_path):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    add_camera(scene, location=(0.0, 0.0, 12.0))
    add_sun(scene)
    beta, start = (0.6, 0.2, 0.0), (-1.0, 0.5, 0.0)
    plane = add_plane(scene, "Runner", size=3.0, location=start)
    key_linear_path(plane, start, beta, scene.restframe.light_speed)
    plane.restframe.motion = 'ANIMATION'
    scene.frame_set(30)  # 1.2 s: about the light travel time from the plane to the camera
    animated = render_exr(scene, tmp_path / "animated.exr")
    assert scene.frame_current == 30

    plane.animation_data_clear()
    plane.location = start
    plane.restframe.motion = 'CONSTANT'
    plane.restframe.velocity = beta
    constant = render_exr(scene, tmp_path / "constant.exr")

    hit = constant["Doppler"][..., 0] > 0
    assert 20 < hit.sum() < hit.size  # the plane and the background are both in view
    np.testing.assert_array_equal(animated["Doppler"][..., 0] > 0, hit)
    np.testing.assert_allclose(animated["Doppler"], constant["Doppler"], atol=1e-5, rtol=0)
    np.testing.assert_allclose(animated["Emission Time"], constant["Emission Time"], atol=1e-5)
    assert constant["Doppler"][hit].std() > 1e-3  # D varies over the plane: a real comparison


def test_trajectory_samples_cover_the_light_travel_time_without_changing_the_frame(scene):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.frame_start = 1
    add_camera(scene, location=(0.0, 0.0, 12.0))
    plane = add_plane(scene, "Runner", location=(0, 0, 0))
    key_linear_path(plane, (0, 0, 0), (0.5, 0, 0), scene.restframe.light_speed)
    plane.restframe.motion = 'ANIMATION'
    scene.frame_set(7)
    out, settings, warnings = export_now(scene)
    assert scene.frame_current == 7 and warnings == []
    (mesh,) = out.meshes
    traj = mesh.trajectory
    assert traj is not None and traj.name == "Runner"
    assert mesh.velocity.is_zero
    np.testing.assert_allclose(mesh.pivot, plane.matrix_world.translation, atol=1e-12)
    # light from 12 units away takes 1.2 s = 28.8 frames: the samples start earlier than that
    assert traj.frames[0] <= 1 - 28.8 and traj.frames[-1] >= 7
    assert np.all(np.diff(traj.frames) <= 1.0 / SUBFRAMES + 1e-9)
    t = (traj.frames - scene.restframe.reference_frame) / FPS
    np.testing.assert_allclose(traj.tau, 10.0 * t)
    np.testing.assert_allclose(traj.position[:, 0], 0.5 * 10.0 * t, atol=1e-4)  # extrapolated linearly
    assert settings.motion_tolerance == pytest.approx(1e-3)


def test_parent_is_static_and_composed(scene):
    add_camera(scene, location=(0.0, 0.0, 12.0))
    parent = bpy.data.objects.new("Rig", None)
    scene.collection.objects.link(parent)
    parent.location = (0.0, 3.0, 0.0)
    parent.rotation_euler = (0.0, 0.0, math.pi / 2)
    plane = add_plane(scene, "Child", location=(0, 0, 0))
    plane.parent = parent
    key_linear_path(plane, (0, 0, 0), (0.5, 0, 0), scene.restframe.light_speed)
    plane.restframe.motion = 'ANIMATION'
    scene.frame_set(13)  # half a second after frame 1: local x = 2.5, rotated onto world +y
    out, _, warnings = export_now(scene)
    traj = out.meshes[0].trajectory
    state = traj.position[np.argmin(abs(traj.frames - 13))]
    np.testing.assert_allclose(state, (0.0, 5.5, 0.0), atol=1e-5)
    assert warnings == []


def test_a_keyed_sharp_turn_is_rounded_for_the_whole_assembly_and_warned(scene, capfd):
    """The world line is built for the body it carries: its corners are rounded for the
    assembly's radius (a child included), and a turn too sharp for its samples is reported."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    add_camera(scene, location=(0.0, 0.0, 12.0))
    add_sun(scene)
    body = add_plane(scene, "Turner", size=2.0)
    for frame, location in ((1, (0.0, 0.0, 0.0)), (13, (3.0, 0.0, 0.0)), (25, (3.0, 3.0, 0.0))):
        body.location = location  # 3 units in half a second at c = 10: 0.6 c along x, then along y
        body.keyframe_insert("location", frame=frame)
    for fc in motion_query.fcurves(body.animation_data.action, getattr(body.animation_data, "action_slot", None)):
        for point in fc.keyframe_points:
            point.interpolation = 'LINEAR'
    arm = add_plane(scene, "Arm", size=1.0, location=(3.0, 0.0, 1.0))
    arm.parent = body  # moves with the body (same Motion): its far corner sets the radius
    body.restframe.motion = arm.restframe.motion = 'ANIMATION'
    scene.frame_set(20)
    out, _, warnings = export_now(scene)
    turner, arm_mesh = sorted(out.meshes, key=lambda m: m.name, reverse=True)
    traj = turner.trajectory
    assert arm_mesh.trajectory is traj and arm_mesh.pivot == pytest.approx(turner.pivot)
    radius = math.sqrt(3.5**2 + 0.5**2 + 1.0**2)  # the arm's corner (3.5, 0.5, 1) from the pivot
    assert traj.body_radius == pytest.approx(radius, rel=1e-6)
    # the 90 degree turn at frame 13 changes gamma*beta by 0.75*sqrt(2): it wants a corner of
    # c*t = gamma * radius * |du| = 4.9 but the samples (1/8 frame = 0.052 apart) leave far less
    at_turn = np.abs(traj.frames[1:-1] - 13.0) < 0.2
    assert np.all(traj.half[at_turn] > 0.0) and traj.half[at_turn].max() == pytest.approx(0.5 * 10 / FPS / SUBFRAMES)
    assert any(w.startswith("Turner: the turn at frame 13") and f"radius {radius:.3g}" in w and "too sharp" in w
               for w in traj.warnings)
    assert warnings == []  # the world line's own warnings reach the user once, from the render:
    capfd.readouterr()
    bpy.ops.render.render()
    reported = capfd.readouterr().out
    assert "Warning: RESTframe: Turner: the turn at frame 13" in reported and "too sharp" in reported


def test_an_animated_body_with_a_nan_corner_gets_the_radius_of_its_finite_vertices(scene, tmp_path):
    add_camera(scene, location=(0.0, 0.0, 12.0))
    add_sun(scene)
    mesh = bpy.data.meshes.new("Shard")
    mesh.from_pydata([(0, 0, 0), (2, 0, 0), (0, 1, 0), (math.nan, 0, 0)], [], [(0, 1, 2), (0, 2, 3)])
    shard = bpy.data.objects.new("Shard", mesh)
    scene.collection.objects.link(shard)
    key_linear_path(shard, (0, 0, 0), (0.5, 0, 0), scene.restframe.light_speed)
    shard.restframe.motion = 'ANIMATION'
    scene.frame_set(30)  # about the light travel time from the shard to the camera: seen near the origin
    out, _, _ = export_now(scene)
    assert out.meshes[0].trajectory.body_radius == 2.0
    passes = render_exr(scene, tmp_path / "shard.exr")
    assert np.all(np.isfinite(passes["Combined"])) and (passes["Doppler"] > 0).any()


def test_faster_than_light_animation_is_refused_naming_object_and_frames(scene):
    add_camera(scene, location=(0.0, 0.0, 12.0))
    plane = add_plane(scene, "Rocket")
    plane.keyframe_insert("location", frame=1)
    plane.location = (2.0 * 10.0 * 0.5, 0.0, 0.0)  # 10 units in 12 frames (0.5 s) at c = 10: 2c
    plane.keyframe_insert("location", frame=13)
    plane.restframe.motion = 'ANIMATION'
    scene.frame_set(20)
    with pytest.raises(export.ExportError, match=r"Rocket: .*not below the speed of light.*between frames"):
        export_now(scene)
    with pytest.raises(RuntimeError, match=r"Rocket: .*between frames"):
        bpy.ops.render.render()


def test_angular_velocity_is_exported_and_renders(scene, tmp_path):
    add_camera(scene, location=(0.0, 0.0, 12.0))
    add_sun(scene)
    spinner = add_plane(scene, "Spinner", location=(0.5, 0, 0))
    spinner.restframe.angular_velocity = (0.0, 0.0, 2.0)
    out, _, warnings = export_now(scene)
    (mesh,) = out.meshes
    assert mesh.angular_velocity == pytest.approx((0.0, 0.0, 2.0))
    assert mesh.pivot == pytest.approx((0.5, 0.0, 0.0))
    passes = render_exr(scene, tmp_path / "spin.exr")
    assert (passes["Doppler"] > 0).sum() > 20
    # too fast: the rim (about 2.1 units from the pivot) would outrun light at c = 10
    spinner.restframe.angular_velocity = (0.0, 0.0, 6.0)
    with pytest.raises(RuntimeError, match="Spinner: spinning this fast"):
        bpy.ops.render.render()


def test_object_time_pass_in_multilayer_exr(scene, tmp_path):
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    add_camera(scene, location=(0.0, 0.0, 10.0))
    add_sun(scene)
    add_plane(scene, "Still", size=6.0)
    scene.frame_set(25)
    passes = render_exr(scene, tmp_path / "clock.exr")
    assert "Object Time" in passes
    hit = passes["Doppler"][..., 0] > 0
    assert hit.sum() > 20
    # a clock at rest in the world frame shows the world time of emission: 1 s minus the light travel
    np.testing.assert_allclose(passes["Object Time"][hit], passes["Emission Time"][hit], atol=1e-5)
    assert np.all(passes["Object Time"][hit] < 1.0) and np.all(passes["Object Time"][hit] > 1.0 - 1.2 / 10 * 10)


def test_keyframed_emission_is_seen_on_the_emitters_own_clock(scene, tmp_path):
    """Optical clocks: an emitter whose strength is keyed to its own time (strength = 1000 +
    24 * seconds, linear) is seen, with the searchlight off, exactly at the clock reading of the
    seen event (the Object Time pass, seconds before the rendered frame's time: the light left
    long ago); approaching at 0.6c that reading runs at D = 2."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.reference_frame = 1
    scene.restframe.searchlight = False
    scene.view_settings.view_transform = 'Standard'
    scene.world = None
    add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0), lens=500)
    glow = add_plane(scene, "Blinker", size=40.0, location=(0.0, 30.0, 0.0), velocity=(0.0, -0.6, 0.0))
    glow.rotation_euler = (math.radians(90), 0.0, 0.0)
    mat = bpy.data.materials.new("glow")
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    bsdf = mat.node_tree.nodes["Principled BSDF"]
    bsdf.inputs["Base Color"].default_value = (0, 0, 0, 1)
    bsdf.inputs["Specular IOR Level"].default_value = 0.0
    bsdf.inputs["Emission Color"].default_value = (1, 1, 1, 1)
    strength = bsdf.inputs["Emission Strength"]
    for frame, value in ((1, 1000.0), (241, 1240.0)):
        strength.default_value = value
        strength.keyframe_insert("default_value", frame=frame)
    animation = mat.node_tree.animation_data
    for fc in motion_query.fcurves(animation.action, getattr(animation, "action_slot", None)):
        fc.extrapolation = 'LINEAR'
        for point in fc.keyframe_points:
            point.interpolation = 'LINEAR'
    glow.data.materials.append(mat)
    scene.render.resolution_x = scene.render.resolution_y = 5  # odd (Blender's minimum is 4): pixel 2 is the axis
    seen = []
    for frame in (25, 37):
        scene.frame_set(frame)
        passes = render_exr(scene, tmp_path / f"f{frame}.exr")
        clock = float(passes["Object Time"][2, 2, 0])
        assert clock < 0.0
        assert float(passes["Combined"][2, 2, 1]) == pytest.approx(1000.0 + 24.0 * clock, rel=1e-5)
        seen.append(clock)
    assert (seen[1] - seen[0]) / (12 / FPS) == pytest.approx(2.0, rel=1e-5)


def test_spin_speed_is_measured_from_the_axis(scene, tmp_path):
    """A pole 10 long and 0.2 thick spinning about its own length: its points are at most
    0.1 sqrt 2 from the axis, so at 50.2 rad/s (c = 10) they move at 0.71 c although its ends are
    5 from the pivot (25 c if measured from there).  About a crosswise axis the same spin is refused
    with the true rim speed."""
    add_camera(scene, location=(0.0, -20.0, 0.0), rotation=(math.radians(90), 0.0, 0.0))
    add_sun(scene, rotation=(math.radians(60), 0.0, 0.0))
    bpy.ops.mesh.primitive_cube_add(size=1.0)
    pole = bpy.context.object
    pole.name = "Pole"
    pole.scale = (0.2, 0.2, 10.0)
    omega = 0.71 * 10.0 / (0.1 * math.sqrt(2.0))
    pole.restframe.angular_velocity = (0.0, 0.0, omega)
    passes = render_exr(scene, tmp_path / "pole.exr")
    assert (passes["Doppler"] > 0).sum() >= 5
    pole.restframe.angular_velocity = (omega, 0.0, 0.0)
    rim = omega * math.hypot(5.0, 0.1) / 10.0
    with pytest.raises(RuntimeError, match=f"Pole: spinning this fast its rim would move at {rim:.5g}"):
        bpy.ops.render.render()


def location_fcurves(obj):
    animation = obj.animation_data
    return motion_query.fcurves(animation.action, getattr(animation, "action_slot", None))


def key_x(obj, keys, interpolation='BEZIER'):
    for frame, x in keys:
        obj.location.x = x
        obj.keyframe_insert("location", index=0, frame=frame)
    for fc in location_fcurves(obj):
        for point in fc.keyframe_points:
            point.interpolation = interpolation
        fc.update()
    obj.restframe.motion = 'ANIMATION'


def speed_in_message(error) -> float:
    import re
    return float(re.search(r"moves at ([0-9.e+]+) c", str(error.value)).group(1))


@pytest.mark.parametrize("interpolation", ['BEZIER', 'LINEAR'])
def test_a_spike_shorter_than_one_sample_is_refused_with_its_true_speed(scene, interpolation):
    """x goes 0 -> 2 -> 0 within a tenth of a frame (samples are 1/8 frame apart, so both
    neighbouring samples see x = 0).  The refusal quotes the curve's true top speed, checked
    against finite differences of Blender's own F-curve evaluation on a 1e-4-frame grid (of
    single-precision frames, as Blender takes them)."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    add_camera(scene)
    spike = add_plane(scene, "Spike")
    key_x(spike, [(1, 0.0), (10.0, 0.0), (10.05, 2.0), (10.1, 0.0), (20, 0.0)], interpolation)
    scene.frame_set(15)
    with pytest.raises(export.ExportError, match=r"Spike: .*not below the speed of light.*between frames") as error:
        export_now(scene)
    (fc,) = location_fcurves(spike)
    frames = np.linspace(9.99, 10.11, 1201).astype(np.float32).astype(np.float64)
    x = np.array([fc.evaluate(f) for f in frames])
    reference = np.max(np.abs(np.diff(x) / np.diff(frames))) * FPS / scene.restframe.light_speed
    assert reference > 50.0
    assert speed_in_message(error) == pytest.approx(reference, rel=2e-3)


def test_a_fast_bezier_bump_is_measured_by_its_derivative(scene):
    """A smooth bump (auto-clamped Bezier keys 4 frames apart) whose top speed is 1.2 c while its
    1/8-frame sample differences stay below it: the figure is the derivative's maximum."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    c = scene.restframe.light_speed
    add_camera(scene)
    bump = add_plane(scene, "Bump")
    # auto-clamped handles: top slope 1.5 x (rise / span) in the middle of the rising segment
    rise = 1.2 * c / FPS * 4 / 1.5
    key_x(bump, [(1, 0.0), (5, 0.0), (9, rise), (13, rise)])
    scene.frame_set(15)
    with pytest.raises(export.ExportError, match=r"Bump: ") as error:
        export_now(scene)
    assert speed_in_message(error) == pytest.approx(1.2, rel=1e-4)
    (fc,) = location_fcurves(bump)
    for key in fc.keyframe_points:  # the same bump 1 % slower is accepted
        key.co.y *= 0.99 / 1.2
        key.handle_left.y *= 0.99 / 1.2
        key.handle_right.y *= 0.99 / 1.2
    out, _, _ = export_now(scene)
    assert out.meshes[0].trajectory is not None


def test_a_constant_interpolation_jump_is_refused_as_a_teleport(scene):
    add_camera(scene)
    hopper = add_plane(scene, "Hopper")
    key_x(hopper, [(1, 0.0), (8, 0.5), (20, 0.5)], 'CONSTANT')
    scene.frame_set(15)
    with pytest.raises(export.ExportError, match=r"Hopper: the keyed location jumps .* at frame 8: infinitely fast"):
        export_now(scene)


@pytest.mark.parametrize("broken", ["value", "handle"])
def test_non_finite_keys_name_the_object(scene, broken):
    add_camera(scene)
    probe = add_plane(scene, "Probe")
    key_x(probe, [(1, 0.0), (10, 1.0)])
    (fc,) = location_fcurves(probe)
    if broken == "value":
        fc.keyframe_points[1].co.y = math.nan
    else:
        fc.keyframe_points[1].handle_left.y = math.inf  # stored as 3.4e38
    scene.frame_set(5)
    with pytest.raises(export.ExportError, match=r"^Probe: the location\[0\] key at frame 10 is not a finite number"):
        export_now(scene)


def test_an_inf_vertex_of_an_animated_body_is_skipped_with_a_warning(scene, tmp_path, capfd):
    """Blender stores an inf typed into a vertex as 3.4e38: its triangles are skipped, as NaN ones
    are, with the warning naming the object; the body's radius and its world line stay finite."""
    add_camera(scene)
    add_sun(scene)
    mesh = bpy.data.meshes.new("Probe")
    mesh.from_pydata([(-2, -1, 0), (-1, -1, 0), (-1, 1, 0), (1, -1, 0), (2, -1, 0), (2, 1, 0)], [],
                     [(0, 1, 2), (3, 4, 5)])
    probe = bpy.data.objects.new("Probe", mesh)
    scene.collection.objects.link(probe)
    key_x(probe, [(1, 0.0), (10, 1.0)])
    probe.data.vertices[0].co.x = math.inf
    scene.frame_set(5)
    out, _, _ = export_now(scene)
    assert out.meshes[0].trajectory.body_radius == pytest.approx(math.sqrt(5.0))
    capfd.readouterr()
    passes = render_exr(scene, tmp_path / "probe.exr")
    assert "Probe: skipped 1 triangles with invalid or non-finite vertices" in capfd.readouterr().out
    assert np.all(np.isfinite(passes["Combined"])) and (passes["Doppler"] > 0).any()


@pytest.mark.parametrize("interpolation, handles", [
    ('BEZIER', "long"),  # outgoing handles reaching past the next key: Blender shortens them
    ('BEZIER', "auto"),
    ('SINE', "auto"),
    ('BACK', "auto"),
    ('ELASTIC', "auto"),
])
def test_keyed_curve_derivative_matches_blenders_own_evaluation(scene, interpolation, handles):
    """The per-segment derivative's maximum equals that of finite differences of Blender's own
    F-curve evaluation on a fine grid (1/2000 frame), for uneven keys and odd handles."""
    from restframe_addon.export.keyed_speed import KeyedCurve, fastest

    obj = add_plane(scene, "Curve")
    key_x(obj, [(1, 0.0), (4, 3.0), (4.5, -1.0), (9, 2.0), (10, 2.0)], interpolation)
    (fc,) = location_fcurves(obj)
    if handles == "long":
        for point in fc.keyframe_points:
            point.handle_left_type = point.handle_right_type = 'FREE'
            point.handle_left = (point.co.x - 0.1, point.co.y - 0.2)
            point.handle_right = (point.co.x + 3.0, point.co.y + 2.0)
        fc.update()
    curve = KeyedCurve.from_fcurve(fc)
    assert curve.vertical() == []
    frames = np.linspace(1.0, 10.0, 18001).astype(np.float32).astype(np.float64)
    values = np.array([fc.evaluate(f) for f in frames])
    reference = np.max(np.abs(np.diff(values) / np.diff(frames)))
    probes = np.unique(np.concatenate([frames[::100], curve.probe_frames()]))
    top, _ = fastest(lambda at: curve.derivative(at)[:, None], probes[(probes >= 1.0) & (probes <= 10.0)])
    assert top == pytest.approx(reference, rel=5e-3)


def test_bezier_handles_that_stop_time_are_refused_as_infinitely_fast(scene):
    """Both handles of a segment as long as the segment: Blender's curve stands still in time at
    its middle while the value moves (a vertical tangent)."""
    add_camera(scene)
    obj = add_plane(scene, "Flick")
    key_x(obj, [(1, 0.0), (5, 0.0), (6, 0.1), (12, 0.1)])
    (fc,) = location_fcurves(obj)
    middle, after = fc.keyframe_points[1], fc.keyframe_points[2]
    middle.handle_right_type = after.handle_left_type = 'FREE'
    middle.handle_right = (7.0, 0.0)
    after.handle_left = (4.0, 0.1)
    fc.update()
    scene.frame_set(10)
    with pytest.raises(export.ExportError, match=r"Flick: .*stand still in time while it moves at frame 5.5"):
        export_now(scene)


def test_keys_are_world_line_samples_without_slivers(scene):
    """A key between the even samples is a sample itself, and no even sample is left within a
    quarter step of it (the corner there keeps its room)."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    add_camera(scene)
    walker = add_plane(scene, "Walker", size=0.5)
    key_x(walker, [(1, 0.0), (10.03, 1.0), (20, 0.0)], 'LINEAR')
    scene.frame_set(15)
    out, _, _ = export_now(scene)
    frames = out.meshes[0].trajectory.frames
    key = float(np.float32(10.03))
    assert key in frames
    assert np.diff(frames).min() >= 0.25 / SUBFRAMES * 0.999
    i = int(np.flatnonzero(frames == key)[0])
    np.testing.assert_allclose(out.meshes[0].trajectory.position[i], (1.0, 0.0, 0.0), atol=1e-6)

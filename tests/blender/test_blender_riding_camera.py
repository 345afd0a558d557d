"""A camera parented to a moving body rides with it (docs/physics.md#observer): from its cockpit the
ship is at rest, so the render equals the same scene with nothing moving -- no aberration, no
Doppler shift, no light-travel delay -- whether the camera has no motion of its own, the ship's
velocity, or the ship's Motion = Animation.  A camera with other motion settings is its own assembly."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, export_now, render_exr
from restframe_addon import motion_query

FPS = 24
C = 10.0  # scene units per second
BETA = 0.8
FRAME = 13  # half a second after the reference frame: the ship has moved 4 units


def ship_scene(scene, ship_motion, camera_motion):
    """A hull and a nose cube, lit by a lamp of the ship, seen from a camera parented behind the hull
    (an offset along the motion, so a camera placed without the ship's Lorentz contraction shows).
    ``ship_motion``: None (at rest), 'CONSTANT' (BETA along x) or 'ANIMATION' (keyed at BETA);
    ``camera_motion``: None (no motion of its own) or 'SAME' (the ship's settings)."""
    scene.render.fps, scene.render.fps_base = FPS, 1.0
    scene.restframe.light_speed = C
    scene.restframe.reference_frame = 1
    scene.restframe.samples = 4
    scene.render.resolution_x, scene.render.resolution_y = 32, 24
    bpy.ops.mesh.primitive_cube_add(size=2.0, location=(0.0, 0.0, 0.0))
    ship = bpy.context.object
    ship.name = "Ship"
    bpy.ops.mesh.primitive_cube_add(size=1.0, location=(2.5, 0.8, 0.3), rotation=(0.3, 0.2, 0.5))
    nose = bpy.context.object
    light = bpy.data.lights.new("Lamp", 'POINT')
    light.energy = 2000.0
    lamp = bpy.data.objects.new("Lamp", light)
    lamp.location = (-3.0, -2.5, 3.0)
    scene.collection.objects.link(lamp)
    camera = add_camera(scene, location=(-7.0, -1.5, 1.2), rotation=(math.radians(82), 0.0, math.radians(-80)))
    for child in (nose, lamp, camera):
        child.parent = ship  # identity parent inverse: the locations are relative to the ship
    if ship_motion == 'ANIMATION':
        for frame in (-60, 60):
            ship.location = (BETA * C * (frame - 1) / FPS, 0.0, 0.0)
            ship.keyframe_insert("location", frame=frame)
        for fc in motion_query.fcurves(ship.animation_data.action, getattr(ship.animation_data, "action_slot", None)):
            fc.extrapolation = 'LINEAR'
            for point in fc.keyframe_points:
                point.interpolation = 'LINEAR'
    members = (ship, nose, lamp) + ((camera,) if camera_motion == 'SAME' else ())
    for obj in members:
        if ship_motion == 'CONSTANT':
            obj.restframe.velocity = (BETA, 0.0, 0.0)
        elif ship_motion == 'ANIMATION':
            obj.restframe.motion = 'ANIMATION'
        obj.update_tag()  # as the property's edit in the UI does: the evaluated copy follows
    scene.frame_set(FRAME)
    return ship, camera


def rgb(scene, path):
    return render_exr(scene, path)["Combined"][..., :3]


CASES = [('CONSTANT', None), ('CONSTANT', 'SAME'), ('ANIMATION', None), ('ANIMATION', 'SAME')]


@pytest.mark.parametrize("ship_motion, camera_motion", CASES,
                         ids=["constant, camera without motion", "constant, camera at the ship's velocity",
                              "animated, camera without motion", "animated, camera animated too"])
def test_the_ship_seen_from_its_cockpit_is_the_ship_at_rest(scene, tmp_path, ship_motion, camera_motion):
    ship_scene(scene, ship_motion, camera_motion)
    exported, _, _ = export_now(scene)
    speed = (np.linalg.norm(exported.camera.velocity.beta) if exported.camera.trajectory is None
             else np.linalg.norm(exported.camera.trajectory.state(np.array([exported.tau_obs]))[1][0]))
    # float32 velocity settings; the keyed path is evaluated in float32 (~1e-4 noise per subframe chord)
    assert speed == pytest.approx(BETA, rel=1e-6 if ship_motion == 'CONSTANT' else 1e-3)
    moving = rgb(scene, tmp_path / "moving.exr")
    for obj in scene.objects:  # the same scene with nothing moving (the keys still place the ship)
        obj.restframe.velocity = (0.0, 0.0, 0.0)
        obj.restframe.motion = 'CONSTANT'
        obj.update_tag()
    static = rgb(scene, tmp_path / "static.exr")
    lit = static.sum(axis=-1) > 0.05
    assert np.count_nonzero(lit) > 0.2 * lit.size, "the ship must fill a fair part of the view"
    # measured: bit-identical at constant velocity; 5e-4 of the brightest pixel animated, the speed noise
    # of the float32 keys above (D^4 - 1 ~ 4 * 1e-4)
    assert np.abs(moving - static).max() <= (1e-5 if ship_motion == 'CONSTANT' else 2e-3) * static.max()


def test_a_camera_with_motion_settings_of_its_own_is_its_own_assembly(scene):
    """The docs' rule for children: other motion settings than the parent's make their own assembly,
    its velocity measured in S and its own location the pivot."""
    ship, camera = ship_scene(scene, 'CONSTANT', None)
    camera.restframe.velocity = (0.0, 0.3, 0.0)
    camera.update_tag()
    exported, _, _ = export_now(scene)
    assert exported.camera.velocity.beta == pytest.approx((0.0, 0.3, 0.0))
    # the contraction along y is about the camera's own origin: its place is its Blender location
    assert exported.camera.matrix[:3, 3] == pytest.approx(np.array(camera.matrix_world.translation), abs=1e-12)


def test_a_riding_camera_sits_at_its_lorentz_contracted_offset_from_the_pivot(scene):
    """In S at world time 0 the camera is where the ship's own points at that offset are: the
    offset along the motion shortened by 1/gamma, as docs/physics.md#rest-shapes places the ship."""
    ship, camera = ship_scene(scene, 'CONSTANT', None)
    exported, _, warnings = export_now(scene)
    beta = float(np.float32(BETA))  # as the property stores it
    gamma = 1.0 / math.sqrt(1.0 - beta**2)
    offset = np.array(camera.matrix_world.translation) - np.array(ship.matrix_world.translation)
    expected = np.array(ship.matrix_world.translation) + offset * np.array([1.0 / gamma, 1.0, 1.0])
    assert exported.camera.matrix[:3, 3] == pytest.approx(expected, abs=1e-12)
    assert exported.camera.velocity.beta == pytest.approx((beta, 0.0, 0.0), abs=1e-15)
    assert camera.restframe.proper_time == pytest.approx((FRAME - 1) / FPS / gamma, rel=1e-6)


def test_a_camera_riding_a_spinning_ship_takes_its_velocity_and_says_it_does_not_spin(scene):
    ship, camera = ship_scene(scene, 'CONSTANT', None)
    ship.restframe.angular_velocity = (0.0, 0.0, 0.1)
    ship.update_tag()
    exported, _, warnings = export_now(scene)
    assert exported.camera.velocity.beta == pytest.approx((float(np.float32(BETA)), 0.0, 0.0), abs=1e-15)
    assert "Camera: the camera does not spin with 'Ship' (it takes its velocity only)" in warnings

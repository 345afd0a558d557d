"""Red team of the core's input checks: a NaN or infinite number anywhere in the camera, a light,
a material or the world (a driver dividing by zero, a script) stops the render with a message
naming the object and the setting, instead of black or NaN pixels without a word."""

import dataclasses

import numpy as np
import pytest

from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import RenderError
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity, WorldTexture
from shapes import look_at_camera, quad, uv_sphere

NAN, INF = float("nan"), float("inf")


def lit_ball(**changes):
    """A lit ball; ``changes`` maps "camera" / "lamp" / "material" / "world_texture" to the fields to replace."""
    v, t = uv_sphere((0, 0, 0), 1.0, 8, 4)
    camera = dataclasses.replace(look_at_camera((0, -6, 0), (0, 0, 0)), **changes.get("camera", {}))
    lamp = dataclasses.replace(Light("Lamp", "SPOT", (2.0, -3.0, 4.0), power=500.0), **changes.get("lamp", {}))
    material = dataclasses.replace(Material("Paint"), **changes.get("material", {}))
    world = dataclasses.replace(WorldTexture(np.full((4, 8, 3), 0.1)), **changes.get("world_texture", {}))
    return Scene(camera=camera, meshes=[Mesh("Ball", v, t)], lights=[lamp], materials=[material],
                 world_texture=world, world_color=changes.get("world_color", (0.05, 0.05, 0.05)))


SETTINGS = RenderSettings(resolution=(5, 4), threads=1)


def test_the_finite_scene_prepares():
    assert prepare(lit_ball(), SETTINGS).scene.lights[0].name == "Lamp"


@pytest.mark.parametrize("part, field, value, named", [
    ("lamp", "power", NAN, "Lamp: its power"),
    ("lamp", "power", INF, "Lamp: its power"),
    ("lamp", "color", (1.0, NAN, 1.0), "Lamp: its color"),
    ("lamp", "position", (NAN, 0.0, 0.0), "Lamp: its position"),
    ("lamp", "matrix", np.full((3, 3), NAN), "Lamp: its world transform"),
    ("lamp", "radius", NAN, "Lamp: its radius"),
    ("lamp", "spot_size", NAN, "Lamp: its spot size"),
    ("lamp", "temperature", INF, "Lamp: its temperature"),
    ("lamp", "power_curve", (np.array([0.0, 1.0]), np.array([1.0, NAN])), "Lamp: its keyed power"),
    ("camera", "matrix", np.full((4, 4), NAN), "Camera: its world transform"),
    ("camera", "frame", np.full((4, 3), NAN), "Camera: its view frame"),
    ("camera", "clip_end", NAN, "Camera: its clip end"),
    ("material", "base_color", (NAN, 0.5, 0.5), "material Paint: its base color"),
    ("material", "roughness", NAN, "material Paint: its roughness"),
    ("material", "emission", (INF, 0.0, 0.0), "material Paint: its emission"),
    ("material", "ior", NAN, "material Paint: its ior"),
    ("world_texture", "strength", NAN, "world World: its strength"),
])
def test_a_non_finite_setting_is_an_error_naming_the_object_and_the_setting(part, field, value, named):
    with pytest.raises(RenderError, match=f"^{named}.* is not a finite number"):
        prepare(lit_ball(**{part: {field: value}}), SETTINGS)


def test_a_non_finite_world_colour_is_an_error():
    with pytest.raises(RenderError, match="world colour .* is not a finite number"):
        prepare(lit_ball(world_color=(0.1, NAN, 0.1)), SETTINGS)


def _ball_and_far_card(distance, card_velocity=(0.0, 0.0, 0.0)):
    v, t = uv_sphere((0, 0, 0), 1.0, 8, 4)
    meshes = [Mesh("Ball", v, t)]
    if distance:
        meshes.append(Mesh("Card", *quad((distance, 0, 0), (1.0, 1.0)), velocity=Velocity(card_velocity),
                           pivot=(distance, 0.0, 0.0)))
    return Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), meshes=meshes)


@pytest.mark.parametrize("distance", [1e5, 1e8])
def test_objects_too_far_apart_for_float32_geometry_are_named(distance):
    """Bodies of one velocity share one float32 embree scene about the middle of their bounds: a
    ball with a card 1e5 units away is rounded by 1.5e-3 of its size (1e8 away it falls apart)."""
    warnings = prepare(_ball_and_far_card(distance), SETTINGS).warnings
    assert len(warnings) == 1 and warnings[0].startswith("Ball, Card: too far from the other objects")


@pytest.mark.parametrize("distance, card_velocity", [(0, (0, 0, 0)), (1e4, (0, 0, 0)), (1e8, (0.5, 0, 0))])
def test_objects_near_enough_or_in_frames_of_their_own_are_not_warned_about(distance, card_velocity):
    assert prepare(_ball_and_far_card(distance, card_velocity), SETTINGS).warnings == ()


def test_an_object_beyond_embrees_reach_is_named():
    """Embree misses triangles whose coordinates reach 2^42 (4.4e12) units: a floor 1e13 across."""
    floor = Mesh("Floor", *quad((0, 0, -1e12), (1e13, 1e13)))
    scene = Scene(camera=look_at_camera((0, -6e12, 1e12), (0, 0, 0)), meshes=[floor])
    warnings = prepare(scene, SETTINGS).warnings
    assert len(warnings) == 1 and warnings[0].startswith("Floor: 1e+13 scene units across, more than Embree can trace")


def _accelerating_ball():
    """A ball speeding up from rest to 0.5 c along x, sampled at 11 times (c*t units)."""
    from restframe_addon.core.motion import Trajectory
    tau = np.linspace(-20.0, 0.0, 11)
    x = 0.5 * 0.5 * (tau + 20.0) ** 2 / 20.0 - 5.0  # x' = 0.5 (tau + 20) / 20: from 0 to 0.5
    trajectory = Trajectory(tau, np.column_stack([x, np.zeros_like(x), np.zeros_like(x)]), name="Probe")
    v, t = uv_sphere((0, 0, 0), 0.5, 8, 4)
    return Scene(camera=look_at_camera((0, -8, 0), (-5, 0, 0)), meshes=[Mesh("Probe", v, t, trajectory=trajectory)])


@pytest.mark.parametrize("tolerance", [NAN, INF, 0.0, -1e-3])
def test_a_motion_tolerance_that_is_not_a_positive_number_is_refused(tolerance):
    """NaN split the world line until Python's recursion depth, for hours, without a word."""
    with pytest.raises(RenderError, match=r"^the motion tolerance must be a positive number"):
        prepare(_accelerating_ball(), RenderSettings(resolution=(5, 4), threads=1, motion_tolerance=tolerance))


def test_a_motion_tolerance_far_too_small_is_an_error_naming_the_body(monkeypatch):
    """1e-9 (the Blender property's floor: what typing 0 gives) would cut this gentle motion into
    millions of inertial segments; it stops at 64 per sample of the world line (at least 20000; here
    1000, to be quick), naming the body."""
    from restframe_addon.core import motion
    monkeypatch.setattr(motion, "MIN_SEGMENT_LIMIT", 1000)
    scene = _accelerating_ball()
    assert len(prepare(scene, RenderSettings(resolution=(5, 4), threads=1, motion_tolerance=1e-3)).frames.frames) > 3
    with pytest.raises(RenderError, match=r"^Probe: following its motion within the Motion Tolerance of 1e-09 "
                                          r"scene units needs more than 1000 inertial segments"):
        prepare(scene, RenderSettings(resolution=(5, 4), threads=1, motion_tolerance=1e-9))

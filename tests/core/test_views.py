"""Several views of one scene (stereo eyes): each its own camera and observation event, the rest frames built once."""

import dataclasses

import numpy as np
from shapes import look_at_camera, quad, uv_sphere

from restframe_addon.core.prepared import prepare, prepare_view
from restframe_addon.core.render import render_tile
from restframe_addon.core.scene import Light, Mesh, RenderSettings, Scene, Velocity

SETTINGS = RenderSettings(resolution=(24, 16), samples=2, threads=1, doppler_mode="FACTOR")


def scene(camera_velocity=Velocity((0.0, 0.0, 0.0))):
    ball = Mesh("ball", *uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12), velocity=Velocity((0.6, 0.0, 0.0)))
    floor = Mesh("floor", *quad((0.0, 0.0, -1.5), (20.0, 20.0)))
    camera = look_at_camera((-0.15, -6.0, 0.5), (0.0, 0.0, 0.0), velocity=camera_velocity)
    return Scene(camera=camera, meshes=[ball, floor], lights=[Light("sun", "SUN", (0, 0, 5))], tau_obs=2.0)


def eye(camera, offset):
    """The camera moved along its own X axis (an eye of a parallel stereo pair)."""
    matrix = np.array(camera.matrix)
    matrix[:3, 3] += offset * matrix[:3, 0]
    return dataclasses.replace(camera, matrix=matrix)


def image(prepared):
    tile = render_tile(prepared, prepared.region)
    return {name: data for name, data in tile.passes.items()}


def test_a_view_renders_as_the_scene_prepared_for_its_camera():
    for velocity in (Velocity((0.0, 0.0, 0.0)), Velocity((0.5, 0.0, 0.0))):
        left = prepare(scene(velocity), SETTINGS)
        right_camera = eye(left.scene.camera, 0.3)
        right = prepare_view(left, right_camera)
        alone = prepare(dataclasses.replace(left.scene, camera=right_camera), SETTINGS)
        assert right.frames is left.frames  # built once
        assert right.camera_tau == alone.camera_tau and right.doppler_range == alone.doppler_range
        if velocity.is_zero:
            assert right.camera_tau == left.camera_tau
        else:  # a moving eye elsewhere along the motion observes at another time of its frame
            assert right.camera_tau != left.camera_tau
        ours, reference = image(right), image(alone)
        for name in reference:
            np.testing.assert_array_equal(ours[name], reference[name])
        assert not np.array_equal(ours["Combined"], image(left)["Combined"])  # the eyes see different images


def test_a_view_with_another_velocity_is_prepared_afresh():
    left = prepare(scene(), SETTINGS)
    other = dataclasses.replace(left.scene.camera, velocity=Velocity((0.3, 0.0, 0.0)))
    view = prepare_view(left, other)
    assert view.frames is not left.frames
    np.testing.assert_array_equal(image(view)["Combined"],
                                  image(prepare(dataclasses.replace(left.scene, camera=other), SETTINGS))["Combined"])

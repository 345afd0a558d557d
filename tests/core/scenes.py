"""The "busy" core scene: every code path of a tile in one small numpy scene (shared by the
prepared-scene, worker and persistent-data tests and the pixel baseline, tools/pixel_baseline.py)."""

import numpy as np
from shapes import box, look_at_camera, quad, uv_sphere

from restframe_addon.core.motion import Trajectory
from restframe_addon.core.scene import Light, Material, Mesh, Scene, Velocity


def busy_scene(camera_velocity=Velocity()):
    """A moving box, a glass ball, a spinning mirror ball and an animated emitter (a keyed glow)
    over a floor, lit by a soft lamp, a sun and a moving area light, seen by a camera with this
    velocity.  The pixel baseline holds its renders bit for bit: change it only with a new baseline."""
    floor = quad((0.0, 0.0, -1.5), (30.0, 30.0))
    cube = box((-2.0, 6.0, 0.0), (1.5, 1.5, 1.5))
    ball = uv_sphere((2.0, 7.0, 0.0), 1.0, segments=24, rings=12)
    spinner = uv_sphere((0.0, 9.0, 1.5), 1.2, segments=24, rings=12)
    comet = uv_sphere((0.0, 0.0, 0.0), 0.6, segments=16, rings=8)
    tau = np.linspace(-40.0, 10.0, 6)
    path = np.stack([4.0 + 0.0 * tau, 8.0 + 0.3 * tau, 0.02 * (tau + 40.0) ** 1.5 * 0.05], axis=1)
    meshes = [
        Mesh("floor", *floor, material_indices=np.zeros(2, int), object_index=1),
        Mesh("cube", *cube, velocity=Velocity((0.6, 0.0, 0.0)), pivot=(-2.0, 6.0, 0.0),
             material_indices=np.full(12, 1), object_index=2),
        Mesh("ball", *ball, velocity=Velocity((0.0, -0.5, 0.2)), pivot=(2.0, 7.0, 0.0),
             material_indices=np.full(len(ball[1]), 2), object_index=3),
        Mesh("spinner", *spinner, pivot=(0.0, 9.0, 1.5), angular_velocity=(0.0, 0.0, 0.4),
             material_indices=np.full(len(spinner[1]), 3), object_index=4),
        Mesh("comet", *comet, trajectory=Trajectory(tau, path, name="comet"),
             material_indices=np.full(len(comet[1]), 4), object_index=5),
    ]
    materials = [Material("floor", (0.7, 0.7, 0.7), roughness=0.8),
                 Material("cube", (0.9, 0.3, 0.2), roughness=0.3),
                 Material("glass", (1.0, 1.0, 1.0), roughness=0.0, transmission=1.0, ior=1.45),
                 Material("mirror", (0.9, 0.9, 0.9), metallic=1.0, roughness=0.0),
                 Material("glow", emission=(0.5, 2.0, 0.5),
                          emission_curve=(np.array([-1e-7, 1e-7]), np.array([0.2, 1.0])))]
    lights = [Light("lamp", "POINT", (0.0, 2.0, 4.0), power=800.0, radius=0.3),
              Light("sun", "SUN", (0.0, 0.0, 10.0), power=2.0, sun_angle=0.05),
              Light("panel", "AREA", (3.0, 4.0, 3.0), power=300.0, velocity=Velocity((0.0, 0.3, 0.0)))]
    return Scene(camera=look_at_camera((0.0, -2.0, 1.0), (0.0, 7.0, 0.0), velocity=camera_velocity), meshes=meshes,
                 materials=materials, lights=lights, light_speed=1.0, tau_obs=9.0)

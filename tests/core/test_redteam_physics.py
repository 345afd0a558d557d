"""Physics spot checks at the edge of the speed range, against closed forms in mpmath: a wall
receding or approaching along the line of sight at beta = 1 - 1e-9 (entered, as the docs say, by
its Lorentz factor).  The centre ray looks along the motion: Doppler factor
D = sqrt((1 - beta) / (1 + beta)) receding, its inverse approaching; the light left the wall's pivot
at tau_e = -L / (1 + beta) (receding) or -L / (1 - beta) (approaching), travelled -tau_e, and the
pivot's clock read tau_e / gamma there; the white glow arrives as D^4 (searchlight on)."""

import dataclasses
import math

import mpmath
import numpy as np
import pytest

from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity
from shapes import look_at_camera, quad, rotation_x

mpmath.mp.dps = 40
DISTANCE = 20.0
LIGHT_SPEED = 299792458.0
GAMMA = float(1 / mpmath.sqrt(1 - (1 - mpmath.mpf("1e-9")) ** 2))  # beta = 1 - 1e-9


def wall(direction):
    """A glowing wall DISTANCE ahead of the camera (looking +y), moving along +y (1: away) or -y (-1)."""
    camera = dataclasses.replace(look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=1e-3), clip_end=1e12)
    return Scene(camera=camera, light_speed=LIGHT_SPEED, world_color=(0, 0, 0),
                 meshes=[Mesh("Wall", *quad((0, DISTANCE, 0), (10.0, 10.0), normal_axis=1),
                              velocity=Velocity((0.0, float(direction), 0.0), lorentz_factor=GAMMA),
                              pivot=(0.0, DISTANCE, 0.0))],
                 materials=[Material("Glow", base_color=(0, 0, 0), emission=(1.0, 1.0, 1.0), specular_ior_level=0.0)])


@pytest.mark.parametrize("direction", [1, -1], ids=["receding", "approaching"])
def test_a_wall_at_one_minus_1e_9_c_along_the_line_of_sight(direction):
    passes = render_image(wall(direction), RenderSettings(resolution=(3, 3), threads=1,
                                                          passes=("Doppler", "Emission Time", "Object Time", "Depth")))
    beta = mpmath.sqrt(1 - 1 / mpmath.mpf(GAMMA) ** 2)
    doppler = mpmath.sqrt((1 - direction * beta) / (1 + direction * beta))
    tau_e = -DISTANCE / (1 + direction * beta)
    assert float(doppler) == pytest.approx(2.236e-5 if direction == 1 else 44721.4, rel=1e-4)  # the speed meant
    centre = {name: float(values[1, 1, 0]) for name, values in passes.items()}
    assert centre["Doppler"] == pytest.approx(float(doppler), rel=1e-6)
    assert centre["Emission Time"] == pytest.approx(float(tau_e / LIGHT_SPEED), rel=1e-6)
    assert centre["Object Time"] == pytest.approx(float(tau_e / GAMMA / LIGHT_SPEED), rel=1e-6)
    assert centre["Depth"] == pytest.approx(float(-tau_e), rel=1e-6)
    assert centre["Combined"] == pytest.approx(float(doppler ** 4), rel=1e-5)


@pytest.mark.parametrize("integrator, colour", [("DIRECT", "OFF"), ("PATH", "OFF"), ("PATH", "SPECTRAL")])
@pytest.mark.parametrize("degrees", [0.0, 30.0, 120.0])
def test_a_soft_sun_gives_a_facing_surface_its_strength(integrator, colour, degrees):
    """A sun of strength S and angular diameter 2h is a disc of radiance S / (pi sin^2 h) (Blender's
    and Cycles' convention, docs/physics.md): wholly above the horizon it gives a Lambert floor the
    irradiance S cos(tilt), whatever its angle, so the floor's radiance is albedo S cos(tilt) / pi.
    Taking the radiance as S over the disc's solid angle, as before, gave S cos(tilt) (1 + cos h) / 2:
    3 % too dark at 30 degrees, 25 % at 120."""
    tilt, albedo, strength = math.radians(20.0), 0.5, 3.0
    floor = Mesh("Floor", *quad((0, 0, 0), (100.0, 100.0)))
    camera = look_at_camera((0, 0, 10), (0, 0, 0), up=(0, 1, 0), fov_half_tan=0.05)
    sun = Light("Sun", "SUN", (0, 0, 5), matrix=rotation_x(tilt), power=strength, sun_angle=math.radians(degrees))
    scene = Scene(camera=camera, meshes=[floor], lights=[sun], world_color=(0, 0, 0),
                  materials=[Material("Matte", base_color=(albedo,) * 3, roughness=1.0, specular_ior_level=0.0)])
    settings = RenderSettings(resolution=(4, 4), samples=256, threads=1, integrator=integrator, max_bounces=0,
                              doppler_mode=colour, passes=("Doppler",))
    seen = render_image(scene, settings)["Combined"][..., 0]
    assert seen.mean() == pytest.approx(albedo * strength * math.cos(tilt) / math.pi, rel=5e-3)

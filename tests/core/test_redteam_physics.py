"""Physics spot checks at the edge of the speed range, against closed forms in mpmath: a wall
receding or approaching along the line of sight at beta = 1 - 1e-9 (entered, as the docs say, by
its Lorentz factor).  The centre ray looks along the motion: Doppler factor
D = sqrt((1 - beta) / (1 + beta)) receding, its inverse approaching; the light left the wall's pivot
at tau_e = -L / (1 + beta) (receding) or -L / (1 - beta) (approaching), travelled -tau_e, and the
pivot's clock read tau_e / gamma there; the white glow arrives as D^4 (searchlight on)."""

import dataclasses

import mpmath
import numpy as np
import pytest

from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Material, Mesh, RenderSettings, Scene, Velocity
from shapes import look_at_camera, quad

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

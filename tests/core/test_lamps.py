"""Lamps that flash and move: the light reaching a surface left the lamp at the retarded event on
its world line, with the strength keyed on the lamp's own clock then.  A flash above a floor lights
a ring bounded by the ellipses |x - lamp| + |x - camera| = c (t_obs - t_flash) (and that for the
flash's end), with a moving lamp's retarded positions."""

import math

import numpy as np
import pytest
from shapes import look_at_camera, quad

from restframe_addon.core.motion import Trajectory
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity

RES = (96, 96)
T_OBS = 20.0  # c = 1: light_speed 1, seconds are lengths
CAMERA = np.array([0.0, -10.0, 8.0])
PULSE = 2.0  # seconds of the lamp's clock
WATTS = 4000.0


def pulse():
    """The flash keyed on the lamp's clock: on from 0 to PULSE (edges 1e-6 s)."""
    return np.array([-1e-6, 0.0, PULSE, PULSE + 1e-6]), np.array([0.0, WATTS, WATTS, 0.0])


def floor_points(camera):
    """Where each pixel-centre ray meets the floor z = 0 (rows from the bottom)."""
    right, up, back = (camera.matrix[:3, i] for i in range(3))
    half = camera.frame[0][0]
    u = ((np.arange(RES[0]) + 0.5) / RES[0] - 0.5) * 2 * half
    v = ((np.arange(RES[1]) + 0.5) / RES[1] - 0.5) * 2 * half
    d = (u[None, :, None] * right + v[:, None, None] * up - back)
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    s = -CAMERA[2] / d[..., 2]
    x = CAMERA + s[..., None] * d
    return x, (s > 0) & np.all(np.abs(x[..., :2]) < 39.0, axis=-1)


def retarded_time(x, start, beta):
    """World time at which light reaching floor points x (at world time t_obs - |x - camera|) left
    a lamp at ``start + beta t``: the earlier root of |x - start - beta t| = t_x - t."""
    t_x = T_OBS - np.linalg.norm(x - CAMERA, axis=-1)
    r = x - start
    b2 = float(beta @ beta)
    # (t_x - t)^2 = |r - beta t|^2  ->  (1 - b2) t^2 - 2 (t_x - r.beta) t + t_x^2 - |r|^2 = 0
    a, half_b, c = 1.0 - b2, -(t_x - r @ beta), t_x**2 - np.einsum("...i,...i", r, r)
    return (-half_b - np.sqrt(half_b**2 - a * c)) / a


def render_flash(light):
    camera = look_at_camera(CAMERA, (0.0, 2.0, 0.0))
    v, t = quad((0.0, 0.0, 0.0), (80.0, 80.0))
    scene = Scene(camera=camera, meshes=[Mesh("floor", v, t)], lights=[light],
                  materials=[Material(base_color=(0.8, 0.8, 0.8))], world_color=(0.0, 0.0, 0.0),
                  tau_obs=T_OBS, light_speed=1.0)
    image = render_image(scene, RenderSettings(resolution=RES, samples=1))["Combined"][..., 0]
    return camera, image


def straight_world_line(start, beta):
    tau = np.linspace(-60.0, 60.0, 241)
    return Trajectory(tau, np.asarray(start) + np.outer(tau, beta), name="lamp", smooth=True)


LAMP = np.array([-1.0, 0.0, 2.0])  # where the lamp is at world time 0 (its clock's zero)
MOVING = np.array([0.6, 0.0, 0.0])


@pytest.mark.parametrize("motion", ["static", "animated 0.6c", "constant 0.6c"])
def test_flash_lights_a_ring_between_the_analytic_ellipses(motion):
    beta = np.zeros(3) if motion == "static" else MOVING
    light = Light("flash", "POINT", tuple(LAMP), power=0.0, power_curve=pulse())
    if motion == "animated 0.6c":
        light.trajectory = straight_world_line(LAMP, beta)
    elif motion == "constant 0.6c":
        light.velocity = Velocity(tuple(beta))
    camera, image = render_flash(light)
    x, on_floor = floor_points(camera)
    gamma = 1.0 / math.sqrt(1.0 - beta @ beta)
    # the flash as world times of its emission events: the lamp's clock runs 1/gamma as fast
    emitted = retarded_time(x, LAMP, beta)
    # one pixel of image distance, in emission time
    step = np.hypot(*np.gradient(emitted))
    inside = on_floor & (emitted > step) & (emitted < gamma * PULSE - step)
    outside = on_floor & ((emitted < -step) | (emitted > gamma * PULSE + step))
    lit = image > 1e-6
    assert inside.sum() > 30 and outside.sum() > 1000
    assert lit[inside].all(), f"{np.count_nonzero(~lit[inside])} dark pixels inside the ring"
    assert not lit[outside].any(), f"{np.count_nonzero(lit[outside])} lit pixels outside the ring"
    # the ring is between the ellipses |x - X_e| + |x - camera| = t_obs - t_e of its first and last
    # emission events: it is thin, unlike the floor a steady lamp lights
    assert lit.sum() < 0.2 * on_floor.sum()


def test_moving_flash_is_not_where_a_static_one_would_be():
    """The retarded positions matter: the 0.6c lamp's ring misses the static lamp's band."""
    light = Light("flash", "POINT", tuple(LAMP), power=0.0, power_curve=pulse(),
                  trajectory=straight_world_line(LAMP, MOVING))
    camera, image = render_flash(light)
    x, on_floor = floor_points(camera)
    static = retarded_time(x, LAMP, np.zeros(3))
    assert np.count_nonzero((image > 1e-6) & ~((static > -0.6) & (static < PULSE + 0.6))) > 20


def test_keyed_colour_is_read_at_emission():
    """A lamp that turns from red to green at clock 0: the floor near the lamp (light sent later) is
    green, far away (sent earlier) red."""
    light = Light("lamp", "POINT", tuple(LAMP), power=WATTS,
                  color_curve=(np.array([0.0, 1e-6]), np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0]])))
    camera = look_at_camera(CAMERA, (0.0, 2.0, 0.0))
    v, t = quad((0.0, 0.0, 0.0), (80.0, 80.0))
    scene = Scene(camera=camera, meshes=[Mesh("floor", v, t)], lights=[light], world_color=(0.0, 0.0, 0.0),
                  tau_obs=T_OBS, light_speed=1.0)
    for mode in ("OFF", "SPECTRAL"):
        image = render_image(scene, RenderSettings(resolution=RES, samples=1, doppler_mode=mode))["Combined"]
        x, on_floor = floor_points(camera)
        emitted = retarded_time(x, LAMP, np.zeros(3))
        green, red = on_floor & (emitted > 0.5), on_floor & (emitted < -0.5)
        assert green.sum() > 50 and red.sum() > 50
        assert np.all(image[green][:, 1] > 3 * image[green][:, 0])
        assert np.all(image[red][:, 0] > 3 * image[red][:, 1])


def test_steady_lamp_on_a_world_line_lights_as_the_constant_velocity_lamp():
    """An animated lamp moving inertially at 0.6c and the same lamp at constant velocity agree
    (retarded position, D^4, the frame map), pixel for pixel to rounding."""
    images = []
    for animated in (False, True):
        light = Light("lamp", "POINT", tuple(LAMP), power=WATTS)
        if animated:
            light.trajectory = straight_world_line(LAMP, MOVING)
        else:
            light.velocity = Velocity(tuple(MOVING))
        images.append(render_flash(light)[1])
    assert images[0].max() > 0
    assert np.abs(images[0] - images[1]).max() < 1e-6 * images[0].max()

"""An accelerating observer: a camera on a keyed hyperbolic world line sees static stars where the
aberration formula for its momentary velocity puts them, whatever its past acceleration, and its
clock reads the analytic proper time; shutter samples observe at their own proper time."""

import math

import numpy as np
import pytest
from shapes import look_at_camera, uv_sphere

from restframe_addon.core.motion import Trajectory
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Material, Mesh, RenderSettings, Scene, Velocity

ACCELERATION = 0.25  # proper acceleration (c = 1, light_speed 1: seconds are lengths)
T_OBS = 2.0  # a T = 0.5: beta = 0.447
RES = (128, 128)
VIEW = np.array([1.0, 0.35, 0.1])  # the camera looks near its direction of motion (+x)
STAR_DISTANCE = 2000.0
STAR_RADIUS = 16.0  # about 1 px across


def hyperbolic(acceleration, start, tau):
    """x(t) of uniform proper acceleration from rest at world time ``start`` (at rest before)."""
    t = np.maximum(tau - start, 0.0)
    return np.column_stack([(np.sqrt(1.0 + (acceleration * t) ** 2) - 1.0) / acceleration,
                            np.zeros_like(tau), np.zeros_like(tau)])


def keyed_world_line(acceleration, start, step=0.02):
    """A densely keyed hyperbolic world line, as Blender's samples of a keyed location are."""
    tau = np.arange(-2.0, T_OBS + 2.0 + step / 2, step)
    return Trajectory(tau, hyperbolic(acceleration, start, tau), name="rocket", smooth=True)


def momentary_beta(acceleration, start, tau):
    u = acceleration * (tau - start)
    return u / math.sqrt(1.0 + u * u)


def aberrated(direction, beta):
    """Direction seen by an observer moving with speed beta along +x (the textbook formula:
    cos theta' = (cos theta + beta) / (1 + beta cos theta), the azimuth about x kept)."""
    d = direction / np.linalg.norm(direction)
    cos_t = d[0]
    cos_new = (cos_t + beta) / (1.0 + beta * cos_t)
    across = d[1:] / max(np.linalg.norm(d[1:]), 1e-300)
    return np.concatenate([[cos_new], math.sqrt(1.0 - cos_new**2) * across])


def star_field():
    """Static stars, as directions from the camera (S), spread over the apparent view."""
    return [np.array([1.0, y, z]) for y in (-0.55, 0.05, 0.6, 1.1) for z in (-0.55, 0.0, 0.45)]


def pixel_of(camera, direction):
    """Image position (px, py) of a camera-frame direction through the test camera's pinhole."""
    right, up, back = (camera.matrix[:3, i] for i in range(3))
    depth = -(direction @ back)
    half = camera.frame[0][0]
    return np.array([(0.5 + 0.5 * (direction @ right) / depth / half) * RES[0],
                     (0.5 + 0.5 * (direction @ up) / depth / half) * RES[1]])


def render_stars(camera, position, shutter=None):
    meshes = []
    for i, d in enumerate(star_field()):
        v, t = uv_sphere(position + STAR_DISTANCE * d / np.linalg.norm(d), STAR_RADIUS, 12, 6)
        meshes.append(Mesh(f"star{i}", v, t, material_indices=np.zeros(len(t), dtype=int)))
    if shutter is not None:
        camera.shutter_interval = shutter
    scene = Scene(camera=camera, meshes=meshes, materials=[Material(emission=(5.0, 5.0, 5.0))],
                  world_color=(0.0, 0.0, 0.0), tau_obs=T_OBS, light_speed=1.0)
    image = render_image(scene, RenderSettings(resolution=RES, samples=9, doppler_mode="OFF",
                                               searchlight=False))["Combined"][..., 0]
    return image


def centroid(image, near):
    """Brightness centroid (px, py) of the star within 5 px of ``near``."""
    x0, y0 = (int(round(c)) for c in near)
    ys, xs = np.mgrid[max(y0 - 5, 0):y0 + 6, max(x0 - 5, 0):x0 + 6]
    weight = image[ys, xs]
    assert weight.sum() > 0, f"no star near {near}"
    return np.array([(weight * (xs + 0.5)).sum(), (weight * (ys + 0.5)).sum()]) / weight.sum()


def camera_on(trajectory=None, velocity=Velocity(), position=None):
    if position is None:
        position = trajectory.state(np.array([T_OBS]))[0][0]
    camera = look_at_camera(position, position + VIEW, up=(0.0, 0.0, 1.0), velocity=velocity)
    camera.trajectory = trajectory
    return camera, position


def star_errors(camera, position, beta, shutter=None):
    image = render_stars(camera, position, shutter)
    errors = []
    for d in star_field():
        expected = pixel_of(camera, aberrated(d, beta))
        if np.all((expected > 6) & (expected < np.array(RES) - 6)):
            errors.append(np.linalg.norm(centroid(image, expected) - expected))
    assert len(errors) >= 6
    return np.array(errors)


@pytest.mark.parametrize("acceleration, start", [(ACCELERATION, 0.0), (2 * ACCELERATION, T_OBS / 2)],
                         ids=["gentle since 0", "twice as hard since 1"])
def test_accelerating_camera_sees_static_stars_aberrated_by_its_momentary_velocity(acceleration, start):
    """Two pasts, one momentary velocity (0.447 c at T_OBS): the same sky, where aberration puts it."""
    trajectory = keyed_world_line(acceleration, start)
    beta = momentary_beta(acceleration, start, T_OBS)
    assert beta == pytest.approx(momentary_beta(ACCELERATION, 0.0, T_OBS))
    camera, position = camera_on(trajectory)
    errors = star_errors(camera, position, beta)
    assert errors.max() < 1.0, errors  # pixels
    # the aberration is large: at rest the stars would be tens of pixels away
    at_rest = [np.linalg.norm(pixel_of(camera, d / np.linalg.norm(d)) - pixel_of(camera, aberrated(d, beta)))
               for d in star_field()]
    assert max(at_rest) > 10.0


def test_accelerating_camera_sees_what_an_inertial_camera_at_its_momentary_velocity_sees():
    trajectory = keyed_world_line(ACCELERATION, 0.0)
    beta = momentary_beta(ACCELERATION, 0.0, T_OBS)
    camera, position = camera_on(trajectory)
    accelerated = render_stars(camera, position)
    # the inertial camera through the same event: its world line (tau, c_ref + beta tau)
    inertial, _ = camera_on(velocity=Velocity((beta, 0.0, 0.0)), position=position)
    inertial.matrix = inertial.matrix.copy()
    inertial.matrix[:3, 3] = position - np.array([beta, 0.0, 0.0]) * T_OBS
    inertial_image = render_stars(inertial, position)
    assert np.abs(accelerated - inertial_image).max() < 0.05 * accelerated.max()


def test_camera_clock_reads_the_analytic_proper_time():
    trajectory = keyed_world_line(ACCELERATION, 0.0)
    for t in (0.5, 1.0, T_OBS, T_OBS + 1.0):
        analytic = math.asinh(ACCELERATION * t) / ACCELERATION
        assert trajectory.proper_time(np.array([t]))[0] == pytest.approx(analytic, rel=1e-5)
        assert trajectory.world_time(np.array([analytic]))[0] == pytest.approx(t, rel=1e-5)


def test_shutter_samples_observe_at_their_own_proper_time_in_their_momentary_frame():
    """A shutter that opens 1.5 s of camera time after the observation event, for an instant:
    the sky of the camera's momentary velocity then (rapidity a (tau_0 + 1.5)), not of T_OBS."""
    trajectory = keyed_world_line(ACCELERATION, 0.0)
    camera, position = camera_on(trajectory)
    later = math.asinh(ACCELERATION * T_OBS) / ACCELERATION + 1.5
    beta = math.tanh(ACCELERATION * later)
    assert beta - momentary_beta(ACCELERATION, 0.0, T_OBS) > 0.15
    # the stars sit around the camera's place at T_OBS; 2000 units away, its move changes nothing visible
    errors = star_errors(camera, position, beta, shutter=(1.5, 1.5))
    assert errors.max() < 1.0, errors


def test_row_boosts_are_the_boosts_of_each_row():
    from restframe_addon.core.lorentz import Boost, RowBoosts

    rng = np.random.default_rng(7)
    beta = rng.uniform(-0.55, 0.55, (50, 3))
    tau, x = rng.normal(size=50), rng.normal(size=(50, 3))
    d = rng.normal(size=(50, 3))
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    rows = RowBoosts(beta)
    t_rows, x_rows = rows.events(tau, x)
    d_rows, w_rows = rows.rays(d)
    for i in range(50):
        boost = Boost.from_velocity(tuple(beta[i]))
        t_i, x_i = boost.events(tau[i], x[i])
        d_i, w_i = boost.rays(d[i])
        assert t_rows[i] == pytest.approx(float(t_i), abs=1e-14)
        np.testing.assert_allclose(x_rows[i], x_i, atol=1e-14)
        np.testing.assert_allclose(d_rows[i], d_i, atol=1e-14)
        assert w_rows[i] == pytest.approx(float(w_i), rel=1e-14)
    t_back, x_back = rows.inverse().events(t_rows, x_rows)
    np.testing.assert_allclose(t_back, tau, atol=1e-14)
    np.testing.assert_allclose(x_back, x, atol=1e-14)


def busy_scene(camera):
    from shapes import quad

    from restframe_addon.core.scene import Light

    floor_v, floor_t = quad((0.0, 0.0, 0.0), (30.0, 30.0))
    ball_v, ball_t = uv_sphere((1.0, 4.0, 1.0), 1.0, 24, 12)
    meshes = [Mesh("floor", floor_v, floor_t),
              Mesh("ball", ball_v, ball_t, velocity=Velocity((0.0, -0.5, 0.0)), pivot=(1.0, 4.0, 1.0))]
    return Scene(camera=camera, meshes=meshes, materials=[Material(base_color=(0.7, 0.6, 0.5))],
                 lights=[Light("sun", "SUN", (0.0, 0.0, 5.0), power=3.0)], world_color=(0.2, 0.3, 0.4),
                 tau_obs=1.0, light_speed=1.0)


def test_an_inertial_world_line_with_lens_and_shutter_renders_as_the_constant_velocity_camera():
    """A straight world line at 0.5c through the same events: the shutter samples' events, lens
    offsets and directions mapped through their (equal) momentary frames give the inertial
    camera's image, to rounding."""
    beta = np.array([0.5, 0.2, 0.0])
    images = []
    for animated in (False, True):
        camera = look_at_camera((0.0, -6.0, 2.0), (0.0, 0.0, 0.5), velocity=Velocity(tuple(beta)))
        camera.aperture_radius, camera.focus_distance, camera.aperture_blades = 0.15, 6.0, 6
        camera.shutter_interval, camera.rolling_shutter_type = (-0.8, 0.8), "TOP"
        if animated:
            tau = np.linspace(-10.0, 10.0, 41)
            position = camera.matrix[:3, 3] + np.outer(tau, beta)  # (tau, c_ref + beta tau)
            camera.trajectory = Trajectory(tau, position, name="camera", smooth=True)
            camera.velocity = Velocity()
            camera.matrix = camera.matrix.copy()
            camera.matrix[:3, 3] = position[25]  # where it is at tau_obs = 1
        images.append(render_image(busy_scene(camera), RenderSettings(resolution=(40, 30), samples=4,
                                                                         doppler_mode="SPECTRAL",
                                                                         spectral_samples=8))["Combined"])
    assert images[0][..., :3].std() > 0.01
    np.testing.assert_allclose(images[1], images[0], rtol=1e-5, atol=1e-6)


def test_shutter_samples_see_the_world_with_the_doppler_factor_of_their_momentary_frame():
    """The world background (at rest in S), seen 1.5 s of camera time after the observation
    event: radiance D^4 with D = 1 / (gamma (1 - beta.d)) for the momentary velocity then."""
    trajectory = keyed_world_line(ACCELERATION, 0.0)
    camera, position = camera_on(trajectory)
    camera.shutter_interval = (1.5, 1.5)
    scene = Scene(camera=camera, world_color=(1.0, 1.0, 1.0), tau_obs=T_OBS, light_speed=1.0)
    res = (16, 16)
    image = render_image(scene, RenderSettings(resolution=res, samples=64))["Combined"][..., 0]
    beta = math.tanh(ACCELERATION * (math.asinh(ACCELERATION * T_OBS) / ACCELERATION + 1.5))
    gamma = 1.0 / math.sqrt(1.0 - beta * beta)
    right, up, back = (camera.matrix[:3, i] for i in range(3))
    half = camera.frame[0][0]
    sub = 8  # each pixel's mean over a sub x sub grid of its area
    u = ((np.arange(res[0] * sub) + 0.5) / (res[0] * sub) - 0.5) * 2 * half
    v = ((np.arange(res[1] * sub) + 0.5) / (res[1] * sub) - 0.5) * 2 * half
    d = u[None, :, None] * right + v[:, None, None] * up - back
    d /= np.linalg.norm(d, axis=-1, keepdims=True)
    fine = (1.0 / (gamma * (1.0 - beta * d[..., 0]))) ** 4
    expected = fine.reshape(res[1], sub, res[0], sub).mean(axis=(1, 3))
    np.testing.assert_allclose(image, expected, rtol=4e-3)  # sampling noise: 0.24% at most, 3e-5 on average
    # at the observation event's velocity the sky would be much dimmer ahead
    now = momentary_beta(ACCELERATION, 0.0, T_OBS)
    assert expected.mean() / ((1.0 / ((1.0 - now * d[..., 0]) / math.sqrt(1.0 - now**2))) ** 4).mean() > 1.5

"""Moving lamps and moving occluders seen from a static white Lambert floor, against references
written here: the lamp's retarded position solved in closed form (a quadratic in the emission time),
textbook boost matrices for its rest-frame angles and Doppler factors, and a quadrature over an
area light's rest-frame surface for soft shadows."""

import math

import numpy as np
import pytest
from references import boost_matrix
from shapes import box, look_at_camera, quad

from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity

WHITE_LAMBERT = Material("white", base_color=(1.0, 1.0, 1.0), specular_ior_level=0.0, roughness=1.0)


def floor_scene(lights, camera, meshes=()):
    floor = quad((0, 0, 0), (40.0, 40.0))  # small: shadow rays start 1e-5 of the frame's size above it
    return Scene(camera=camera, meshes=[Mesh("floor", *floor), *meshes], lights=lights,
                 materials=[WHITE_LAMBERT], world_color=(0, 0, 0))


def looking_down(height, fov_half_tan=0.01):
    return look_at_camera((0, 0, height), (0, 0, 0), up=(0, 1, 0), fov_half_tan=fov_half_tan)


def render(scene, tau, res=(9, 9), **options):
    scene.tau_obs = tau
    return render_image(scene, RenderSettings(resolution=res, threads=1, **options))["Combined"][..., 0]


def lamp_on_floor(point, tau_hit, lamp0, beta, power, cone_half_angle=None):
    """Radiance of the white Lambert floor at (tau_hit, point) lit by a point lamp at lamp0 + beta tau
    (emitting along -z within a sharp cone if given): the light left the lamp at the retarded time
    tau_r, |point - lamp(tau_r)| = tau_hit - tau_r, arriving from d = (lamp(tau_r) - point) / r with
    D = 1 / (gamma (1 + beta.d)); irradiance P / (4 pi) D^4 cos / r^2."""
    beta, lamp0, point = (np.asarray(a, dtype=np.float64) for a in (beta, lamp0, point))
    gamma = 1.0 / math.sqrt(1.0 - beta @ beta)
    # |q + beta t|^2 = (tau_hit - t)^2 with q = lamp0 - point: (b^2 - 1) t^2 + 2 (q.beta + tau_hit) t + q^2 - tau_hit^2 = 0
    q = lamp0 - point
    a, b, c = beta @ beta - 1.0, 2.0 * (q @ beta + tau_hit), q @ q - tau_hit**2
    tau_r = (-b + math.sqrt(b * b - 4 * a * c)) / (2 * a)  # the root before tau_hit
    assert tau_r < tau_hit
    r = tau_hit - tau_r
    d = (q + beta * tau_r) / r
    doppler = 1.0 / (gamma * (1.0 + beta @ d))
    value = power / (4 * math.pi) * doppler**4 * d[2] / r**2 / math.pi
    if cone_half_angle is not None:  # the cone is the lamp's own: the floor event in the lamp's frame
        to_lamp = boost_matrix(beta)
        event = to_lamp @ np.array([tau_hit, *point])
        lamp_rest = (to_lamp @ np.array([0.0, *lamp0]))[1:]
        towards = lamp_rest - event[1:]
        if towards[2] / np.linalg.norm(towards) < math.cos(cone_half_angle):
            value = 0.0
    return value, doppler, r


@pytest.mark.parametrize("tau_hit,expect_doppler", [(0.0, 1.25), (5.0, 1 / (1.25 * 1.36))],
                         ids=["approaching", "receding"])
def test_moving_point_lamp_lights_the_floor_from_its_retarded_position(tau_hit, expect_doppler):
    """A lamp 2 above the floor passing at 0.6c.  Seen from the floor point below the camera at
    tau = 0 its light left it at x = -1.5 (r = 2.5, cos = 0.8, D = 1.25); at tau = 5 at x = +1.5
    (D = 1 / (1.25 * 1.36)).  Aiming at its present position, dropping D^4 or taking its rest-frame
    distance r / D all change the number."""
    lamp = Light("lamp", "POINT", (0.0, 0.0, 2.0), power=1000.0, velocity=Velocity((0.6, 0.0, 0.0)))
    value, doppler, r = lamp_on_floor((0, 0, 0), tau_hit, (0, 0, 2.0), (0.6, 0, 0), 1000.0)
    assert doppler == pytest.approx(expect_doppler) and r == pytest.approx(2.5)
    got = render(floor_scene([lamp], looking_down(1.0)), tau_hit + 1.0)
    assert got[4, 4] == pytest.approx(value, rel=1e-5)


def test_moving_occluder_shadows_the_floor_when_the_shadow_ray_passes_it():
    """A lamp at rest 3 above the floor; a plate (2 x 1, at height 1) slides along x at 0.9c.  The
    shadow ray from the floor point seen at hit time tau_hit meets height 1 at tau_hit - 1, where the
    plate's centre is at 0.9 (tau_hit - 1), half-width 1/gamma = 0.436: in shadow for tau_hit = 1, lit
    for tau_hit = 0 and 2.  The camera is 14.1 away (its ray passes beside the plate), so a shadow ray
    started at the observation time would find the plate 12.7 further on."""
    plate = Mesh("plate", *box((0, 0, 1.0), (2.0, 1.0, 0.01)), velocity=Velocity((0.9, 0.0, 0.0)), pivot=(0, 0, 1.0))
    camera = look_at_camera((0, -10.0, 10.0), (0, 0, 0), fov_half_tan=0.001)
    scene = floor_scene([Light("lamp", "POINT", (0.0, 0.0, 3.0), power=1000.0)], camera, [plate])
    lit = 1000.0 / (4 * math.pi * 9.0) / math.pi
    distance = math.hypot(10.0, 10.0)
    for tau_hit, expected in ((0.0, lit), (1.0, 0.0), (2.0, lit)):
        assert render(scene, tau_hit + distance, res=(3, 3))[1, 1] == pytest.approx(expected, rel=1e-5), tau_hit


def test_moving_spot_cone_is_the_lamps_own():
    """A sharp spot (cone half-angle atan 0.5) 2 above the floor, pointing down, passing at 0.6c.
    Along a row of the floor the lit stretch is where the floor event, mapped into the lamp's frame,
    lies inside the cone: in that frame the cone's footprint is |x| < 1, in the floor's frame it is
    contracted and seen at the light's retarded position."""
    half = math.atan(0.5)
    spot = Light("spot", "SPOT", (0.0, 0.0, 2.0), power=1000.0, spot_size=2 * half, spot_blend=0.0,
                 velocity=Velocity((0.6, 0.0, 0.0)))
    height, res = 30.0, (301, 1)
    camera = looking_down(height, fov_half_tan=0.15)
    tau_obs = 32.0
    got = render(floor_scene([spot], camera), tau_obs, res=res)[0]
    xs = ((np.arange(res[0]) + 0.5) / res[0] * 2 - 1) * 0.15 * height  # the floor point of each pixel
    expected = []
    for x in xs:
        s = math.hypot(height, x)
        expected.append(lamp_on_floor((x, 0, 0), tau_obs - s, (0, 0, 2.0), (0.6, 0, 0), 1000.0, half)[0])
    expected = np.array(expected)
    assert 20 < np.count_nonzero(expected) < res[0] - 20
    edge = np.convolve(expected > 0, [1, 1, 1], mode="same") % 3 != 0  # pixels beside the cone's edge
    np.testing.assert_allclose(got[~edge], expected[~edge], rtol=1e-4, atol=1e-9)


def seen_from_the_floor(points, tau_hit, beta):
    """For light-frame points (the lamp at rest, moving with beta in the floor's frame) seen from the
    floor event (tau_hit, origin): the rest-frame unit directions and distances toward them, and in the
    floor's frame the directions and Doppler factors -- the photon's 4-momentum boosted back."""
    to_lamp, from_lamp = boost_matrix(beta), boost_matrix(-beta)
    floor_event = to_lamp @ np.array([tau_hit, 0.0, 0.0, 0.0])
    towards = points - floor_event[1:]
    r_rest = np.linalg.norm(towards, axis=1)
    e_rest = towards / r_rest[:, None]
    photon = np.column_stack([np.ones(len(e_rest)), -e_rest]) @ from_lamp.T  # lamp frame -> floor frame
    doppler = photon[:, 0]
    return e_rest, r_rest, -photon[:, 1:] / doppler[:, None], doppler


def plate_leaves_visible(e_floor, edge=-0.3):
    """The static plate at height 1 covers x < edge: a ray from the origin along e is unblocked beyond it."""
    return e_floor[:, 0] / e_floor[:, 2] >= edge


def half_shadowed_floor(light):
    plate = Mesh("plate", *quad((-10.3, 0, 1.0), (20.0, 20.0)))  # covers x < -0.3 at height 1
    return floor_scene([light], looking_down(0.5, fov_half_tan=0.001), [plate])


def test_moving_area_light_soft_shadow_matches_a_rest_frame_quadrature():
    """A 1 x 1 area light 2 above the floor, facing down, passing at 0.6c, half hidden from the floor
    point below the camera by a static plate at height 1 covering x < -0.3: a penumbra.

    Reference: the irradiance as an integral over the light's rest-frame surface,
    E = int L' D^2 cos_surface cos_light dA / r'^2 (L' = P / (pi A); the solid angle the floor sees is
    the rest-frame one over D^2), each point's direction, D and visibility from textbook boosts of
    the photon's 4-momentum; a 200 x 200 midpoint grid."""
    beta = np.array([0.6, 0.0, 0.0])
    power, tau_hit = 1000.0, 1.0
    area = Light("area", "AREA", (0.0, 0.0, 2.0), power=power, area_size=(1.0, 1.0), velocity=Velocity(tuple(beta)))
    got = render(half_shadowed_floor(area), tau_hit + 0.5, res=(3, 3), samples=1024).mean()

    grid = (np.arange(200) + 0.5) / 200 - 0.5
    gx, gy = np.meshgrid(grid, grid)
    points = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, 2.0)])  # the lamp's pivot has n.p = 0
    e_rest, r_rest, e_floor, doppler = seen_from_the_floor(points, tau_hit, beta)
    visible = plate_leaves_visible(e_floor)
    radiance = power / (math.pi * 1.0)
    irradiance = np.sum(radiance * doppler**2 * e_floor[:, 2] * e_rest[:, 2] / r_rest**2 * visible) / 200**2
    assert 0.2 < visible.mean() < 0.8
    assert got == pytest.approx(irradiance / math.pi, rel=0.03)


def test_moving_soft_spot_light_penumbra_matches_a_rest_frame_quadrature():
    """A soft spot light (radius 0.4; Blender's soft lamp, which RESTframe samples as a disc facing the
    surface in the lamp's frame) 2 above the floor, pointing down with a sharp cone edge near the floor
    point, passing at 0.6c; the same static half-plate as for the area light makes a penumbra.

    Reference: the average over the rest-frame disc (a 400 x 64 polar midpoint grid, uniform in area)
    of P / (4 pi) x cone(rest-frame angle) x D^4 cos_surface / r^2 x visibility, with r = D r' the distance
    in the floor's frame; directions and D from textbook boosts."""
    beta = np.array([0.6, 0.0, 0.0])
    power, tau_hit, radius = 1000.0, 1.0, 0.4
    half = math.radians(28.0)  # the floor event is 21 degrees off the axis in the lamp frame, the disc +-11
    spot = Light("spot", "SPOT", (0.0, 0.0, 2.0), power=power, radius=radius, spot_size=2 * half, spot_blend=0.0,
                 velocity=Velocity(tuple(beta)))
    got = render(half_shadowed_floor(spot), tau_hit + 0.5, res=(3, 3), samples=1024).mean()

    centre = np.array([0.0, 0.0, 2.0])
    (axis,), _, _, _ = seen_from_the_floor(centre[None], tau_hit, beta)
    t1 = np.cross(axis, [0.0, 1.0, 0.0])
    t1 /= np.linalg.norm(t1)
    t2 = np.cross(axis, t1)
    rho = radius * np.sqrt((np.arange(400) + 0.5) / 400)
    phi = 2 * np.pi * (np.arange(64) + 0.5) / 64
    rr, pp = np.meshgrid(rho, phi)
    points = centre + (rr * np.cos(pp)).ravel()[:, None] * t1 + (rr * np.sin(pp)).ravel()[:, None] * t2
    e_rest, r_rest, e_floor, doppler = seen_from_the_floor(points, tau_hit, beta)
    visible = plate_leaves_visible(e_floor)
    cone = e_rest[:, 2] > math.cos(half)  # from the lamp down to the floor event, in the lamp's frame
    r = doppler * r_rest
    irradiance = np.mean(power / (4 * math.pi) * cone * doppler**4 * e_floor[:, 2] / r**2 * visible)
    assert 0.2 < np.mean(visible & cone) < 0.8 and cone.mean() < 0.95
    assert got == pytest.approx(irradiance / math.pi, rel=0.03)

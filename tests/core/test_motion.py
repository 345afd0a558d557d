"""Motion beyond constant velocity: moving observer, animated (accelerated) world lines, rotation."""

import math

import mpmath as mp
import numpy as np
import pytest
from scipy import ndimage
from shapes import HyperbolicBall, box, look_at_camera, quad, uv_sphere

from restframe_addon.core.camera import primary_rays
from restframe_addon.core.frames import FrameMap, MotionSettings, build_frames
from restframe_addon.core.lorentz import Boost
from restframe_addon.core.motion import Trajectory, segment_world_line
from restframe_addon.core.render import RenderError, render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity
from restframe_addon.core.tracer import occluded, trace_nearest


def gamma_of(beta):
    return 1.0 / math.sqrt((1.0 - beta) * (1.0 + beta))


def settings(res=(33, 33), **kw):
    return RenderSettings(resolution=res, threads=kw.pop("threads", 1), **kw)


# ---------------------------------------------------------------- moving observer

def test_wigner_rotation_of_the_frame_chain_is_43_degrees():
    """Camera at 0.9c along -x and an object at 0.9c along +y (both in S): the map between their
    frames is a boost times a rotation of 42.9 degrees (Thomas-Wigner), which the chain keeps."""
    chain = FrameMap([Boost.from_velocity((-0.9, 0, 0)).inverse(), Boost.from_velocity((0, 0.9, 0))])
    columns = []
    for e in np.eye(4):
        tau, x = chain.events(np.array(e[0]), e[1:])
        columns.append(np.concatenate([[tau], x]))
    lorentz = np.stack(columns, axis=1)
    # the object frame's velocity seen from the camera frame: the pure-boost part
    u = np.linalg.solve(lorentz, [1.0, 0, 0, 0])
    pure = Boost.from_velocity(u[1:] / u[0]).matrix()
    rotation = lorentz @ np.linalg.inv(pure)
    assert np.allclose(rotation[0], [1, 0, 0, 0], atol=1e-12) and np.allclose(rotation[:, 0], [1, 0, 0, 0], atol=1e-12)
    angle = math.degrees(math.acos((np.trace(rotation[1:, 1:]) - 1) / 2))
    g1 = g2 = gamma_of(0.9)
    g = g1 * g2
    expected = math.degrees(math.acos((1 + g + g1 + g2) ** 2 / ((1 + g) * (1 + g1) * (1 + g2)) - 1))
    assert angle == pytest.approx(expected, abs=1e-9)
    assert angle == pytest.approx(42.9, abs=0.05)


def outline_angles(mask, camera, res):
    """Angles from the camera axis of the hit/miss boundary (pixel-pair midpoints), camera frame."""
    pts = []
    for axis in (0, 1):
        a = mask[:-1, :] if axis == 0 else mask[:, :-1]
        b = mask[1:, :] if axis == 0 else mask[:, 1:]
        ys, xs = np.nonzero(a != b)
        pts.append(np.column_stack([xs + 0.5, ys + 1.0]) if axis == 0 else np.column_stack([xs + 1.0, ys + 0.5]))
    p = np.concatenate(pts)
    _, d, _, _, _ = primary_rays(camera, p[:, 0], p[:, 1], res)
    forward = -camera.matrix[:3, 2]
    return np.arccos(np.clip(d @ forward, -1, 1))


@pytest.mark.parametrize("beta", [0.0, 0.5, 0.9, -0.6])
def test_camera_flying_toward_a_sphere_sees_it_shrink_by_aberration(beta):
    """tan(theta'/2) = sqrt((1 - b)/(1 + b)) tan(theta/2), theta = asin(R/L) at the observation event."""
    res = (301, 301)
    distance, radius = 6.0, 1.0
    camera = look_at_camera((0, -distance, 0), (0, 0, 0), fov_half_tan=0.3, velocity=Velocity((0, beta, 0)))
    ball = uv_sphere((0, 0, 0), radius, 256, 128)
    passes = render_image(Scene(camera=camera, meshes=[Mesh("ball", *ball)], tau_obs=0.0),
                          settings(res, film_transparent=True, threads=0))
    angles = outline_angles(passes["Combined"][..., 3] > 0.5, camera, res)
    theta = math.asin(radius / distance)
    expected = 2 * math.atan(math.sqrt((1 - beta) / (1 + beta)) * math.tan(theta / 2))
    pixel = 2 * 0.3 / res[0]
    assert abs(angles.mean() - expected) < 0.3 * pixel
    assert np.max(np.abs(angles - expected)) < 0.8 * pixel


# ---------------------------------------------------------------- animated world lines

def straight(beta, pivot, tau=np.linspace(-60, 60, 11), name="ball"):
    return Trajectory(tau, np.asarray(pivot) + np.outer(tau, beta), name=name)


def test_constant_velocity_entered_as_animation_renders_the_same():
    beta, pivot = np.array([0.5, -0.6, 0.1]), np.array([0.5, 2.0, 0.3])
    v, t = uv_sphere(pivot, 1.0, 32, 16)
    camera = look_at_camera((0, -8, 1), (0, 0, 0))
    const = Scene(camera=camera, meshes=[Mesh("ball", v, t, velocity=Velocity(tuple(beta)), pivot=tuple(pivot))], tau_obs=3.0)
    anim = Scene(camera=camera, meshes=[Mesh("ball", v, t, pivot=tuple(pivot), trajectory=straight(beta, pivot))], tau_obs=3.0)
    a = render_image(const, settings((40, 40)))
    b = render_image(anim, settings((40, 40)))
    for name in ("Combined", "Doppler", "Depth", "Emission Time", "Object Time"):
        assert np.allclose(a[name], b[name], rtol=1e-5, atol=1e-5), name
    assert a["Combined"][..., 3].sum() > 0


def hyperbola(alpha, x0, tau):
    """Uniform proper acceleration 1/alpha along x through (0, x0)."""
    x = x0 - alpha + np.sqrt(alpha**2 + tau**2)
    return np.column_stack([x, np.zeros_like(tau), np.zeros_like(tau)])


def analytic_crossing(alpha, x0, tau_o, x_o, y_o):
    """World time of the hyperbola's event on the past light cone of (tau_o, (x_o, y_o, 0)), mpmath."""
    alpha, x0, tau_o, x_o, y_o = (mp.mpf(v) for v in (alpha, x0, tau_o, x_o, y_o))
    xs = x_o - x0 + alpha
    k = xs**2 + alpha**2 + y_o**2 - tau_o**2
    a, b, c = 4 * xs**2 - 4 * tau_o**2, -4 * k * tau_o, 4 * xs**2 * alpha**2 - k**2
    roots = [(-b + sgn * mp.sqrt(b * b - 4 * a * c)) / (2 * a) for sgn in (1, -1)]

    def residual(r):  # squaring admitted a spurious root: keep the one on the cone
        return abs((tau_o - r) ** 2 - (xs - mp.sqrt(alpha**2 + r**2)) ** 2 - y_o**2)

    return min((r for r in roots if r < tau_o), key=residual)


def test_hyperbolic_world_line_matches_its_analytic_light_cone_crossing():
    alpha, x0 = 2.0, 0.0  # proper acceleration 0.5; speed 0.995 at tau = +-20
    tau = np.linspace(-20, 20, 8001)
    traj = Trajectory(tau, hyperbola(alpha, x0, tau), name="rocket")
    events = [(5.0, 2.5, -4.0), (12.0, -2.0, -6.0), (0.0, 1.0, -1.0), (25.0, 30.0, -5.0)]
    got = traj.light_cone_crossing(np.array([e[0] for e in events]), np.array([[e[1], e[2], 0.0] for e in events]))
    for g, e in zip(got, events):
        expected = analytic_crossing(alpha, x0, *e)
        # the sampled world line deviates from the hyperbola by ~ a dtau^2 / 8 per knot
        assert abs(mp.mpf(float(g)) - expected) < 1e-5 * (1 + abs(expected)), (e, g, expected)


def test_accelerated_sphere_is_seen_where_its_light_left_it():
    """A small sphere on the hyperbola, seen from a static camera: its image centre points at the
    analytic retarded position and its pass values give that emission time."""
    alpha, x0 = 2.0, 0.0
    tau = np.linspace(-20, 20, 4001)
    radius = 0.05
    v, t = uv_sphere((0, 0, 0), radius, 32, 16)
    cam_pos = np.array([1.0, -6.0, 0.0])
    tau_obs = 8.0
    tau_e = float(analytic_crossing(alpha, x0, tau_obs, cam_pos[0], cam_pos[1]))
    seen_at = hyperbola(alpha, x0, np.array([tau_e]))[0]
    camera = look_at_camera(cam_pos, seen_at, fov_half_tan=0.03)
    traj = Trajectory(tau, hyperbola(alpha, x0, tau), name="rocket")
    scene = Scene(camera=camera, meshes=[Mesh("rocket", v, t, pivot=(0, 0, 0), trajectory=traj)], tau_obs=tau_obs,
                  light_speed=1.0)
    res = (61, 61)
    passes = render_image(scene, settings(res, film_transparent=True, motion_tolerance=1e-4))
    mask = passes["Combined"][..., 3] > 0.5
    assert mask.sum() > 20
    ys, xs = np.nonzero(mask)
    # the image is centred on the retarded position (to a pixel: the view is aimed there)
    assert abs(xs.mean() - 30) < 1.5 and abs(ys.mean() - 30) < 1.5
    times = passes["Emission Time"][..., 0][mask]
    assert np.all(np.abs(times - tau_e) < 2 * radius)


def test_sudden_turn_at_0_99c_gives_no_nan_and_no_tear():
    """A right-angle turn at 0.99c: the corner is rounded over a proper time >= R |d(gamma beta)| so
    the body stays in one piece, every inertial segment is within the tolerance, and the image is
    finite and whole."""
    tau = np.array([-400.0, 0.0, 400.0])
    pos = np.array([[-396.0, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 396.0, 0.0]])
    v, t = uv_sphere((0, 0, 0), 1.0, 48, 24)
    traj = Trajectory(tau, pos, name="comet", body_radius=1.0)
    assert traj.warnings == []
    segments = segment_world_line(traj, tau[0], tau[-1], 1e-3)
    assert max(s.error for s in segments) <= 1e-3
    # continuity: neighbouring segments place the pivot within the tolerance at their common time
    for a, b in zip(segments[:-1], segments[1:]):
        pa = a.position + a.beta * (a.end - a.mid)
        pb = b.position + b.beta * (b.start - b.mid)
        assert np.linalg.norm(pa - pb) <= 2e-3
    assert 2 * traj.half[0] / gamma_of(0.99) >= 1.0 * np.linalg.norm(np.diff(traj.beta, axis=0)) * gamma_of(0.99) - 1e-9
    for tau_obs in (-30.0, 0.0, 20.0, 60.0):
        camera = look_at_camera((-5, 8, 0), traj.state(np.array([tau_obs - 9.0]))[0][0], fov_half_tan=0.6)
        scene = Scene(camera=camera, meshes=[Mesh("comet", v, t, pivot=(0, 0, 0), trajectory=traj)], tau_obs=tau_obs)
        passes = render_image(scene, settings((48, 48), film_transparent=True))
        for name, data in passes.items():
            assert np.all(np.isfinite(data)), name
        mask = passes["Combined"][..., 3] > 0
        if mask.any():
            _, pieces = ndimage.label(mask)
            assert pieces == 1, tau_obs


def test_accelerated_body_does_not_shadow_itself():
    """Neighbouring inertial segments of one body disagree by up to the tolerance: shadow and
    secondary rays start beyond that, so the lit side of an accelerating ball has no speckles."""
    alpha = 400.0  # gentle: many segments, quick to trace; light along the motion stays on the x axis
    tau = np.linspace(-20, 20, 401)
    v, t = uv_sphere((0, 0, 0), 1.0, 64, 32)
    traj = Trajectory(tau, hyperbola(alpha, 0.0, tau), name="ball")
    camera = look_at_camera((0.0, -8.0, 0.0), (0.0, 0.0, 0.0), fov_half_tan=0.25)
    # sunlight along the motion: a neighbouring segment's ball, offset along x, would block it
    sun = Light("sun", "SUN", (9, 0, 0), power=3.0, matrix=np.array([[0, 0, 1], [0, 1, 0], [-1, 0, 0]], float))
    mats = [Material("white", base_color=(0.8, 0.8, 0.8), specular_ior_level=0.0)]
    for tolerance in (5e-2, 1e-2, 1e-3):
        scene = Scene(camera=camera, meshes=[Mesh("ball", v, t, pivot=(0, 0, 0), trajectory=traj)], lights=[sun],
                      materials=mats, tau_obs=8.0, world_color=(0, 0, 0))
        assert len(segment_world_line(traj, tau[0], tau[-1], tolerance)) >= 4
        passes = render_image(scene, settings((48, 48), motion_tolerance=tolerance))
        facing = (passes["Depth"][..., 0] < 1e9) & (passes["Normal"][..., 0] > 0.3)
        assert facing.sum() > 50
        assert np.all(passes["Combined"][..., 0][facing] > 0.0)


def strongly_accelerated_ball(tolerance, camera=None):
    """A ball of radius 0.8 turning around with proper acceleration 0.5 (R a = 0.4, so its front
    and back accelerate 0.71 and 1.67 times as hard as its centre), sampled every 0.1 (the samples
    stray 6e-4 from the hyperbola): the analytic ball and the tracer's frames."""
    ball = HyperbolicBall(alpha=2.0, radius=0.8)
    tau = np.linspace(-10.0, 10.0, 201)
    v, t = uv_sphere((0, 0, 0), ball.radius, 48, 24)
    scene = Scene(camera=camera or look_at_camera((0, -5, 0), (0, 0, 0)),
                  meshes=[Mesh("ball", v, t, pivot=(0, 0, 0), trajectory=Trajectory(tau, ball.centre(tau), name="ball"))])
    return ball, build_frames(scene, motion_settings=MotionSettings(tolerance))


FACETS = 0.005  # the 48 x 24 UV sphere lies within this of the round one


@pytest.mark.parametrize("tolerance", [1e-1, 1e-2])
def test_accelerated_ball_is_seen_from_outside_where_the_analytic_ball_is(tolerance):
    """Camera rays against the exact Born-rigid ball: each one that meets the ball hits its surface
    (within the tolerance) before going inside it.  The inertial segments' windows once followed
    each segment's own simultaneity, which left wedges between neighbours at the front and back of
    the ball, where rays slipped inside and showed its far side from within."""
    tau_obs = 3.0  # the ball is seen at about t = -2, moving at 0.7c toward -x and braking
    camera = look_at_camera((0, -5, 0), HyperbolicBall(2.0, 0.8).centre(-2.0)[0], fov_half_tan=0.25)
    ball, frames = strongly_accelerated_ball(tolerance, camera)
    res = (40, 40)
    ys, xs = np.mgrid[0:res[1], 0:res[0]]
    x0, d, s_lo, s_hi, _ = primary_rays(camera, xs.ravel() + 0.5, ys.ravel() + 0.5, res)
    x0 = np.array(x0)
    tau = np.full(len(d), tau_obs)
    hits = trace_nearest(frames, frames.camera, tau, x0, d, s_lo, s_hi)
    hit = hits.frame >= 0
    assert hit.sum() > 300
    bound = tolerance + FACETS
    deepest_before_hit = ball.deepest(tau, x0, d, s_lo, np.where(hit, hits.s, s_hi), step=bound / 4)
    inside = deepest_before_hit < -bound
    assert not inside.any(), f"{inside.sum()} of {hit.sum()} rays went {-deepest_before_hit.min():.3f} deep into the ball"
    on_surface = ball.margin(tau[hit] - hits.s[hit], x0[hit] + hits.s[hit, None] * d[hit])
    assert np.all(np.abs(on_surface) < bound)


def test_accelerated_ball_blocks_shadow_rays_as_the_analytic_ball_does():
    """Shadow rays against the exact Born-rigid ball.  Rays toward a lamp from its lit side never
    come closer to it than where they start: light cannot pass through the ball's own past (with
    uniform acceleration the ball is a geodesic ball of Rindler optical space, which light leaving
    it never re-enters), and the tracer lets them through.  Rays passing through earlier events of
    the ball, at its front, back and sides, are blocked, and near misses are not."""
    tolerance = 1e-2
    ball, frames = strongly_accelerated_ball(tolerance)
    bound = 2 * tolerance + FACETS
    rng = np.random.default_rng(7)
    normals = rng.normal(size=(60, 3))
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    t_centre = np.repeat([-3.0, -1.0, 0.5, 2.0], 15)
    t_s, x_s = ball.surface_event(t_centre, normals)
    # from the lit side toward a lamp at rest
    lamp = np.array([3.0, -4.0, 5.0])
    to_lamp = lamp - x_s
    reach = np.linalg.norm(to_lamp, axis=1)
    to_lamp /= reach[:, None]
    facing = np.array([float(Boost.from_velocity((float(b), 0.0, 0.0)).rays(e)[0] @ n)
                       for b, e, n in zip(ball.velocity(t_centre), to_lamp, normals)])
    lit = np.flatnonzero(facing > 0.2)
    start = ball.margin(t_s[lit] - bound, x_s[lit] + bound * to_lamp[lit])
    assert len(lit) > 20 and np.all(start > 0)
    assert np.all(ball.deepest(t_s[lit], x_s[lit], to_lamp[lit], bound, reach[lit], step=bound / 4) >= start - 1e-12)
    # through (or just past) the ball: rays whose events 3 units along are body points at 0.5 radii
    # or points at 1.1 radii (rest frame)
    directions = rng.normal(size=(60, 3))
    directions /= np.linalg.norm(directions, axis=1, keepdims=True)
    scale = np.where(np.arange(60) % 2 == 0, 0.5, 1.1)[:, None]
    t_b, x_b = ball.surface_event(t_centre, normals * scale)
    tau_b, x_b = t_b + 3.0, x_b - 3.0 * directions
    deepest = ball.deepest(tau_b, x_b, directions, 0.0, 6.0, step=bound / 4)
    clear = np.flatnonzero(np.abs(deepest) > bound)
    assert 20 <= np.count_nonzero(deepest[clear] < 0) <= len(clear) - 10
    tau0 = np.concatenate([t_s[lit], tau_b[clear]])
    x0 = np.concatenate([x_s[lit], x_b[clear]])
    d = np.concatenate([to_lamp[lit], directions[clear]])
    s_lo = np.concatenate([np.full(len(lit), bound), np.zeros(len(clear))])
    s_hi = np.concatenate([reach[lit], np.full(len(clear), 6.0)])
    expected = np.concatenate([np.zeros(len(lit), bool), deepest[clear] < 0])
    assert np.array_equal(occluded(frames, frames.world, tau0, x0, d, s_lo, s_hi), expected)


def test_turn_too_sharp_for_the_samples_warns():
    tau = np.array([-1.0, 0.0, 1.0])
    pos = np.array([[-0.9, 0.0, 0.0], [0.0, 0.0, 0.0], [0.0, 0.9, 0.0]])
    traj = Trajectory(tau, pos, name="comet", frames=np.array([10.0, 11.0, 12.0]), body_radius=5.0)
    assert traj.warnings and "frame 11" in traj.warnings[0] and "comet" in traj.warnings[0]


def test_faster_than_light_animation_is_refused_naming_object_and_frames():
    tau = np.array([0.0, 1.0, 2.0, 3.0])
    pos = np.array([[0, 0, 0], [0.5, 0, 0], [1.7, 0, 0], [2.0, 0, 0]], float)
    with pytest.raises(ValueError, match=r"Probe.*frames 5-6"):
        Trajectory(tau, pos, name="Probe", frames=np.array([4.0, 5.0, 6.0, 7.0]))
    v, t = box()
    good = Trajectory(tau, pos * 0.1, name="Probe")
    good.position[2] = [1.7, 0, 0]
    with pytest.raises(ValueError, match="Probe"):
        Trajectory(good.tau, good.position, name="Probe")


def test_over_c_animation_is_a_render_error():
    v, t = box()
    with pytest.raises(RenderError, match="Probe"):
        scene = Scene(camera=look_at_camera((0, -5, 0), (0, 0, 0)),
                      meshes=[Mesh("Probe", v, t, velocity=Velocity((0.0, 0.0, 1.0)))])
        render_image(scene, settings((8, 8)))


# ---------------------------------------------------------------- optical clocks

@pytest.mark.parametrize("animated", [False, True])
def test_clock_approaching_at_0_6c_is_seen_running_at_d_equal_2(animated):
    """The Object Time pass shows the body's own clock at the seen event: approaching head-on at
    0.6c it advances 2 s per second of observation (D = 2)."""
    beta = np.array([0.0, -0.6, 0.0])
    pivot = np.array([0.0, 30.0, 0.0])
    wall = quad(pivot, (50, 50), normal_axis=1)
    mesh = Mesh("clock", *wall, pivot=tuple(pivot),
                trajectory=straight(beta, pivot, np.linspace(-200, 200, 5)) if animated else None,
                velocity=Velocity(tuple(beta)))
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01)
    c = 10.0
    seen = []
    for t_obs in (1.0, 1.5):
        scene = Scene(camera=camera, meshes=[mesh], tau_obs=c * t_obs, light_speed=c)
        seen.append(render_image(scene, settings((3, 3)))["Object Time"][1, 1, 0])
    assert (seen[1] - seen[0]) / 0.5 == pytest.approx(2.0, rel=1e-5)


def test_animated_emission_follows_the_emitters_own_clock():
    """An emitter blinking in its own time (keys in seconds of its clock), approaching at 0.6c,
    is seen blinking twice as fast; at rest it follows the observer's clock."""
    pivot = np.array([0.0, 30.0, 0.0])
    wall = quad(pivot, (50, 50), normal_axis=1)
    keys = (np.array([-100.0, 100.0]), np.array([-100.0, 100.0]))  # emission = own clock in seconds
    c = 10.0
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01)
    for beta, rate in ((0.0, 1.0), (0.6, 2.0)):
        mesh = Mesh("blinker", *wall, velocity=Velocity((0.0, -beta, 0.0)), pivot=tuple(pivot))
        mats = [Material("glow", base_color=(0, 0, 0), emission=(1.0, 1.0, 1.0), specular_ior_level=0.0,
                         emission_curve=keys)]
        seen = []
        for t_obs in (1.0, 1.5):
            scene = Scene(camera=camera, meshes=[mesh], materials=mats, tau_obs=c * t_obs, light_speed=c,
                          world_color=(0, 0, 0))
            passes = render_image(scene, settings((3, 3), searchlight=False))
            seen.append((passes["Combined"][1, 1, 1], passes["Object Time"][1, 1, 0]))
        # closed form: the wall (y = 30 - beta tau) is seen from the origin at tau_obs where its light left
        # at tau_e = (tau_obs - 30) / (1 - beta), from y_e = tau_obs - tau_e; its clock there reads
        # gamma (tau_e - beta (30 - y_e)) (0 at its origin event (0, pivot)); with the searchlight off the
        # emission is exactly the curve at that reading
        gamma = 1.0 / math.sqrt(1.0 - beta**2)
        for t_obs, (emission, clock) in zip((1.0, 1.5), seen):
            tau_e = (c * t_obs - 30.0) / (1.0 - beta)
            expected = gamma * (tau_e - beta * (30.0 - (c * t_obs - tau_e))) / c
            assert clock == pytest.approx(expected, rel=1e-5, abs=1e-5)
            assert emission == pytest.approx(expected, rel=1e-5, abs=1e-5)
        assert (seen[1][0] - seen[0][0]) / 0.5 == pytest.approx(rate, rel=1e-5)


# ---------------------------------------------------------------- rotation

def spinning_scene(omega_z, res_fov=0.4, shape="box", light_speed=1.0, tau=0.0):
    v, t = box((0, 0, 0), (1.0, 1.0, 1.0)) if shape == "box" else uv_sphere((0, 0, 0), 1.0, 64, 32)
    mesh = Mesh("top", v, t, pivot=(0, 0, 0), angular_velocity=(0.0, 0.0, omega_z), object_index=3)
    camera = look_at_camera((0, -5, 0.6), (0, 0, 0), fov_half_tan=res_fov)
    return Scene(camera=camera, meshes=[mesh], tau_obs=tau, light_speed=light_speed)


def test_rim_at_or_beyond_c_is_refused():
    with pytest.raises(RenderError, match="top"):
        render_image(spinning_scene(1.5), settings((8, 8)))  # edges 0.71 from the axis: 1.06 c


def test_rim_speed_counts_the_distance_from_the_axis():
    """At omega 1.2 the unit cube's corners are 0.87 from the pivot (1.04 c if measured from there)
    but its vertical edges only 0.71 from the axis: 0.85 c, so it renders."""
    passes = render_image(spinning_scene(1.2), settings((16, 16)))
    assert (passes["Depth"][..., 0] < 1e9).sum() > 10


@pytest.mark.parametrize("omega", [0.3, 1.0])
def test_every_hit_lies_on_the_body_in_the_pose_of_its_own_time(omega):
    """Spinning fast (edges up to 0.71 c), each hit point, turned back by the pose of its own
    emission time, lies on the unit cube's surface (the fixed-point iteration converged)."""
    scene = spinning_scene(omega, tau=2.0)
    res = (41, 41)
    passes = render_image(scene, settings(res, motion_tolerance=1e-6))
    mask = passes["Depth"][..., 0] < 1e9
    assert mask.sum() > 100
    ys, xs = np.nonzero(mask)
    _, d, _, _, _ = primary_rays(scene.camera, xs + 0.5, ys + 0.5, res)
    depth = passes["Depth"][..., 0][mask].astype(np.float64)
    # depth is float32 in the pass: recompute from emission time (s = tau_obs - tau_e for a static camera)
    s = scene.tau_obs - passes["Emission Time"][..., 0][mask].astype(np.float64) * scene.light_speed
    assert np.allclose(s, depth, rtol=1e-5)
    points = scene.camera.matrix[:3, 3] + depth[:, None] * d
    angle = omega * (scene.tau_obs - depth)  # pose angle at each hit's time (clock zero at tau = 0)
    c, s_ = np.cos(-angle), np.sin(-angle)
    local = np.column_stack([c * points[:, 0] - s_ * points[:, 1], s_ * points[:, 0] + c * points[:, 1], points[:, 2]])
    assert np.allclose(np.max(np.abs(local), axis=1), 0.5, atol=2e-4)


def test_spinning_body_with_loose_tolerance_and_rays_that_miss_it():
    """Rays that miss the spinning body (or whose pose iteration ends at once) leave it unhit."""
    scene = spinning_scene(0.8, res_fov=2.0)
    passes = render_image(scene, settings((24, 24), motion_tolerance=0.3))
    hit = passes["Depth"][..., 0] < 1e9
    assert 0 < hit.sum() < hit.size
    assert np.all(passes["IndexOB"][..., 0][hit] == 3)


def test_spinning_surface_doppler_is_its_local_speed():
    """A sphere spinning about z, camera at rest: D = sqrt(1 - v^2) / (1 + v.d) with v = omega x r."""
    omega = 0.6
    scene = spinning_scene(omega, shape="sphere", res_fov=0.3)
    res = (31, 31)
    passes = render_image(scene, settings(res, motion_tolerance=1e-8))
    mask = passes["Depth"][..., 0] < 1e9
    ys, xs = np.nonzero(mask)
    _, d, _, _, _ = primary_rays(scene.camera, xs + 0.5, ys + 0.5, res)
    points = scene.camera.matrix[:3, 3] + passes["Depth"][..., 0][mask][:, None].astype(np.float64) * d
    velocity = np.cross([0.0, 0.0, omega], points)
    expected = np.sqrt(1 - np.einsum("ij,ij->i", velocity, velocity)) / (1 + np.einsum("ij,ij->i", velocity, d))
    assert np.allclose(passes["Doppler"][..., 0][mask], expected, rtol=2e-4)
    assert expected.max() > 1.3 and expected.min() < 0.7  # both limbs, blue and red

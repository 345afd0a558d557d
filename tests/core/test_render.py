"""Render-level physics checks: numbers measured from images, against closed forms."""

import math

import numpy as np
import pytest
from embreex import rtcore_scene
from embreex.mesh_construction import TriangleMesh
from shapes import box, look_at_camera, quad, uv_sphere

from restframe_addon.core.camera import primary_rays
from restframe_addon.core.render import RenderError, render_image
from restframe_addon.core.scene import Camera, Light, Material, Mesh, RenderSettings, Scene, Velocity


def gamma_of(beta):
    return 1.0 / math.sqrt((1.0 - beta) * (1.0 + beta))


def settings(res=(33, 33), **kw):
    return RenderSettings(resolution=res, threads=kw.pop("threads", 1), **kw)


def test_doppler_head_on_approach_on_the_axis_ray():
    """Looking straight at a wall approaching at 0.9c: D = gamma (1 + beta) on the exact axis ray."""
    v, t = quad((0.0, 20.0, 0.0), (400.0, 400.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)),
                  meshes=[Mesh("wall", v, t, velocity=Velocity((0.0, -0.9, 0.0)), pivot=(0, 20, 0))])
    passes = render_image(scene, settings((33, 33)))
    d = passes["Doppler"][16, 16, 0]
    assert abs(d - gamma_of(0.9) * 1.9) < 1e-6 * d
    # half a pixel off the axis the factor is already measurably smaller
    assert passes["Doppler"][16, 17, 0] < d - 1e-6


def test_doppler_perpendicular_to_motion_is_one_over_gamma():
    """A wall sliding sideways at 0.8c, seen along the perpendicular (observer frame): D = 1/gamma."""
    v, t = quad((0.0, 10.0, 0.0), (1e4, 40.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)),
                  meshes=[Mesh("wall", v, t, velocity=Velocity((0.8, 0.0, 0.0)), pivot=(0, 10, 0))])
    passes = render_image(scene, settings((33, 33)))
    assert abs(passes["Doppler"][16, 16, 0] - 0.6) < 1e-6
    row = passes["Doppler"][16, :, 0]
    assert row[0] > row[-1]  # blue-shifted on the side it comes from (-x is where it approaches from)


def pixel_directions(camera, res, px, py):
    _, d, _, _, _ = primary_rays(camera, np.asarray(px, float), np.asarray(py, float), res)
    return d


def outline_directions(mask, camera, res):
    """Sky directions of the boundary between hit and missed pixels (midpoints of the pixel pairs)."""
    pts = []
    h, w = mask.shape
    for axis in (0, 1):
        a = mask[:-1, :] if axis == 0 else mask[:, :-1]
        b = mask[1:, :] if axis == 0 else mask[:, 1:]
        ys, xs = np.nonzero(a != b)
        if axis == 0:
            pts.append(np.column_stack([xs + 0.5, ys + 1.0]))
        else:
            pts.append(np.column_stack([xs + 1.0, ys + 0.5]))
    p = np.concatenate(pts)
    return pixel_directions(camera, res, p[:, 0], p[:, 1])


def fit_cone(directions):
    """Best circle on the unit sphere through the directions: (axis, half-angle, residuals in radians)."""
    centre = directions.mean(axis=0)
    _, _, vt = np.linalg.svd(directions - centre)
    axis = vt[2] * np.sign(vt[2] @ centre)
    angles = np.arccos(np.clip(directions @ axis, -1.0, 1.0))
    return axis, angles.mean(), angles - angles.mean()


@pytest.mark.parametrize("beta", [0.0, 0.5, 0.9])
def test_moving_sphere_outline_is_a_circle_on_the_sky(beta):
    """Penrose-Terrell: a sphere's outline stays a circle in angles, whatever its speed.

    The sphere sits off-axis so its flat-image outline is an ellipse; the test is in angles.
    Its angular radius equals the one a rest-frame observer sees (arcsin R/d') mapped by aberration.
    """
    res = (241, 241)
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.8)
    centre = np.array([3.0, 10.0, 2.0])
    v, t = uv_sphere(centre, 1.5, segments=256, rings=128)
    scene = Scene(camera=camera, meshes=[Mesh("ball", v, t, velocity=Velocity((beta, 0.0, 0.0)), pivot=tuple(centre))],
                  tau_obs=12.0)
    passes = render_image(scene, settings(res, film_transparent=True, threads=0))
    mask = passes["Combined"][..., 3] > 0.5
    dirs = outline_directions(mask, camera, res)
    axis, half_angle, residual = fit_cone(dirs)
    pixel_angle = 2 * 0.8 / res[0]
    assert np.max(np.abs(residual)) < 0.75 * pixel_angle
    # flat-image check that this is not trivially round: the image outline is elongated
    ys, xs = np.nonzero(mask)
    if beta == 0.0:
        assert (xs.max() - xs.min()) != (ys.max() - ys.min())
    # predicted cone: in the sphere's rest frame the observation event sees arcsin(R / d')
    from restframe_addon.core.lorentz import Boost
    boost = Boost.from_velocity((beta, 0.0, 0.0))
    tau_e, x_e = boost.events(np.array(12.0), np.zeros(3))
    centre_rest = centre + boost.gamma_minus_one * (boost.n @ centre) * boost.n if beta else centre
    to_centre = centre_rest - x_e
    expected_rest = math.asin(1.5 / np.linalg.norm(to_centre))
    rest_dirs, _ = boost.rays(dirs)
    rest_axis = to_centre / np.linalg.norm(to_centre)
    rest_angles = np.arccos(np.clip(rest_dirs @ rest_axis, -1, 1))
    # the polygonal sphere (256 x 128) is within 1e-4 R of the true one
    assert np.max(np.abs(rest_angles - expected_rest)) < 0.75 * pixel_angle * (1 + beta) * gamma_of(beta)


def plain_lambert_render(camera, res, meshes, light_pos, power, albedo, world):
    """An ordinary (non-relativistic) ray tracer: one embree scene, Lambert + point light + shadow."""
    scene = rtcore_scene.EmbreeScene()
    verts = np.concatenate([m[0] for m in meshes])
    offs = np.cumsum([0] + [len(m[0]) for m in meshes[:-1]])
    tris = np.concatenate([m[1] + o for m, o in zip(meshes, offs)])
    TriangleMesh(scene, verts.astype(np.float32), tris.astype(np.int32))
    ys, xs = np.mgrid[0:res[1], 0:res[0]]
    o, d, _, _, _ = primary_rays(camera, xs.ravel() + 0.5, ys.ravel() + 0.5, res)
    out = scene.run(o.astype(np.float32), d.astype(np.float32), output=1)
    hit = out["primID"] >= 0
    rgb = np.tile(np.asarray(world, float), (len(d), 1))
    p = o[hit] + out["tfar"][hit, None] * d[hit]
    tri = verts[tris[out["primID"][hit]]]
    n = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    n *= -np.sign(np.einsum("ij,ij->i", n, d[hit]))[:, None]
    to_l = np.asarray(light_pos) - p
    r = np.linalg.norm(to_l, axis=1)
    l = to_l / r[:, None]
    cos = np.clip(np.einsum("ij,ij->i", n, l), 0, None)
    start = (p + 1e-4 * n).astype(np.float32)
    blocked = scene.run(start, l.astype(np.float32), dists=(r - 2e-4).astype(np.float32), query="OCCLUDED") >= 0
    e = power / (4 * np.pi) * cos / r**2 * ~blocked
    rgb[hit] = np.asarray(albedo) / np.pi * e[:, None]
    return rgb.reshape(res[1], res[0], 3)


def test_static_scene_equals_plain_ray_tracer_at_any_time():
    """With nothing moving the finite speed of light changes nothing."""
    res = (48, 40)
    camera = look_at_camera((0.5, -7, 2.0), (0, 0, 0.3), aspect=res[0] / res[1])
    ball = uv_sphere((0, 0, 0.5), 1.0, 48, 24)
    floor = quad((0, 0, -0.5), (8, 8))
    world = (0.05, 0.06, 0.07)
    reference = plain_lambert_render(camera, res, [ball, floor], (2, -3, 4), 800.0, (0.8, 0.8, 0.8), world)
    for tau in (0.0, 1e6):
        scene = Scene(camera=camera, meshes=[Mesh("ball", *ball), Mesh("floor", *floor)],
                      lights=[Light("lamp", "POINT", (2, -3, 4), power=800.0)],
                      materials=[Material(base_color=(0.8, 0.8, 0.8), specular_ior_level=0.0)], world_color=world, tau_obs=tau)
        got = render_image(scene, settings(res))["Combined"][..., :3]
        diff = np.abs(got - reference)
        # float32 shadow-ray offsets may flip a handful of pixels on the terminator
        assert np.mean(diff > 1e-4 * (reference + 1e-3)) < 0.01
        assert np.median(diff) < 1e-6


def test_far_from_the_origin_shading_is_unchanged():
    """The same lit scene moved 1e9 units away renders the same (offsets scale with the scene's
    size and a few ulps of its position, not with its distance from the origin)."""
    res = (32, 24)
    far = np.array([1e9, 7e8, 3e8])
    images = []
    for shift in (np.zeros(3), far):
        camera = look_at_camera(np.array([0.5, -7, 2.0]) + shift, np.array([0, 0, 0.3]) + shift, aspect=res[0] / res[1])
        ball = uv_sphere(tuple(np.array([0, 0, 0.5]) + shift), 1.0, 48, 24)
        floor = quad(tuple(np.array([0, 0, -0.5]) + shift), (8, 8))
        scene = Scene(camera=camera, meshes=[Mesh("ball", *ball), Mesh("floor", *floor)],
                      lights=[Light("lamp", "POINT", tuple(np.array([2, -3, 4]) + shift), power=800.0)])
        images.append(render_image(scene, settings(res))["Combined"][..., :3])
    near, moved = images
    assert np.median(np.abs(moved - near)) < 1e-5
    assert np.mean(np.abs(moved - near) > 1e-3 * (near + 1e-2)) < 0.01


def ball_scene(beta, tau=3.0):
    v, t = uv_sphere((0, 0, 0), 1.0, 32, 16)
    floor = quad((0, 0, -1.2), (20, 20))
    return Scene(camera=look_at_camera((0, -6, 1), (0, 0, 0)),
                 meshes=[Mesh("ball", v, t, velocity=Velocity((beta, 0.0, 0.3 * beta))), Mesh("floor", *floor)],
                 lights=[Light("lamp", "POINT", (3, -3, 4), power=1500.0, velocity=Velocity((0.0, beta, 0.0)))],
                 tau_obs=tau)


def test_tiny_speed_matches_rest():
    """b = 1e-12 renders like b = 0: no 0/0, no discontinuity at rest."""
    a = render_image(ball_scene(0.0), settings())
    b = render_image(ball_scene(1e-12), settings())
    for name in ("Combined", "Doppler", "Depth"):
        assert np.allclose(a[name], b[name], rtol=1e-6, atol=1e-6), name


def test_nearer_object_emitting_earlier_is_hidden():
    """Visibility is decided by emission time in the observer frame, not by rest-frame distance.

    A big screen approaching at 0.9c stands at distance 5 at tau = 0, a small static tile at 10.
    At the observation event tau = 0 the screen's visible light left it when it was 50 away,
    behind the tile: the tile hides the screen at the centre, the screen shows around it.
    """
    screen = quad((0.0, 5.0, 0.0), (400.0, 400.0), normal_axis=1)
    tile = quad((0.0, 10.0, 0.0), (2.0, 2.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)),
                  meshes=[Mesh("screen", *screen, velocity=Velocity((0.0, -0.9, 0.0)), pivot=(0, 5, 0), object_index=1),
                          Mesh("tile", *tile, object_index=2)])
    passes = render_image(scene, settings((33, 33)))
    assert passes["IndexOB"][16, 16, 0] == 2
    assert passes["Doppler"][16, 16, 0] == 1.0
    assert abs(passes["Depth"][16, 16, 0] - 10.0) < 1e-5
    # 13.6 degrees off axis (outside the tile): the screen, seen where it was s = 5 / (cos - 0.9) away
    cos = 1.0 / math.hypot(1.0, 0.5 * 8.0 / 16.5)
    assert passes["IndexOB"][16, 8, 0] == 1
    assert abs(passes["Depth"][16, 8, 0] - 5.0 / (cos - 0.9)) < 1e-4
    # beyond the aberration cone cos > 0.9 the approaching screen is not seen at all
    assert passes["IndexOB"][0, 0, 0] == 0
    # light arriving at tau = 5 left the screen at tau = 0 from distance 5, in front of the tile
    later = render_image(Scene(camera=scene.camera, meshes=scene.meshes, tau_obs=5.0), settings((33, 33)))
    assert later["IndexOB"][16, 16, 0] == 1
    assert abs(later["Depth"][16, 16, 0] - 5.0) < 1e-5


@pytest.mark.parametrize("beta,start,expect_moving_seen", [(-0.9, 5.0, False), (0.9, 10.0, True)],
                         ids=["approaching screen hidden", "receding tile seen"])
def test_visibility_is_decided_by_the_observer_path_length_not_the_rest_frame_one(beta, start, expect_moving_seen):
    """A wall moving along the line of sight (start away at tau = 0) and a static wall 12 away, seen at
    tau = 0.  Closed form: the moving wall is seen at s = start / (1 + beta) -- approaching at 0.9c from
    5 away, s = 50 (behind the static wall) but s' = s / D = 50 / 4.36 = 11.5 in its own frame; receding
    at 0.9c from 10 away, s = 5.26 (in front) but s' = 22.9.  The smaller s wins, whatever s' says."""
    moving = quad((0.0, start, 0.0), (2.0, 2.0) if beta > 0 else (400.0, 400.0), normal_axis=1)
    still = quad((0.0, 12.0, 0.0), (400.0, 400.0) if beta > 0 else (2.0, 2.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)),
                  meshes=[Mesh("moving", *moving, velocity=Velocity((0.0, beta, 0.0)), pivot=(0, start, 0),
                               object_index=1), Mesh("still", *still, object_index=2)])
    passes = render_image(scene, settings((33, 33)))
    s = start / (1.0 + beta)
    doppler = math.sqrt((1 - beta) / (1 + beta))
    assert s / doppler < 12.0 if beta < 0 else s / doppler > 12.0  # the rest-frame path length says the opposite
    seen = passes["IndexOB"][16, 16, 0], passes["Depth"][16, 16, 0], passes["Doppler"][16, 16, 0]
    if expect_moving_seen:
        assert seen == (1, pytest.approx(s, rel=1e-6), pytest.approx(doppler, rel=1e-6))
    else:
        assert seen == (2, pytest.approx(12.0, rel=1e-6), 1.0)


@pytest.mark.parametrize("levels", [0, 2, 4])
def test_factor_display_paints_d_across_the_frames_own_range(levels):
    """FACTOR mode: grey = (D - D_min) / (D_max - D_min) over the frame (optionally in N levels), with
    D = 1 / (gamma (1 + beta.d)) of each pixel's camera-ray direction d for a wall sliding across the
    view at 0.8c (closed form): brightest where it approaches, on the left."""
    beta = 0.8
    v, t = quad((0.0, 10.0, 0.0), (1e4, 1e4), normal_axis=1)
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.8)
    res = (31, 9)
    scene = Scene(camera=camera, meshes=[Mesh("wall", v, t, velocity=Velocity((beta, 0.0, 0.0)), pivot=(0, 10, 0))])
    passes = render_image(scene, settings(res, doppler_mode="FACTOR", doppler_levels=levels))
    ys, xs = np.mgrid[0:res[1], 0:res[0]]
    d = pixel_directions(camera, res, xs.ravel() + 0.5, ys.ravel() + 0.5)
    doppler = 1.0 / (gamma_of(beta) * (1.0 + beta * d[:, 0]))
    grey = (doppler - doppler.min()) / (doppler.max() - doppler.min())
    if levels:
        grey = np.minimum(np.floor(grey * levels), levels - 1) / (levels - 1)
    rgb = passes["Combined"][..., :3].reshape(-1, 3)
    np.testing.assert_allclose(rgb, np.repeat(grey[:, None], 3, axis=1), atol=1e-5)
    assert rgb[:, 0].reshape(res[1], res[0])[4, 0] == pytest.approx(1.0, abs=1e-5)


def test_emission_time_pass_is_world_time_of_the_hit():
    v, t = quad((0.0, 20.0, 0.0), (400.0, 400.0), normal_axis=1)
    c = 10.0
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)), light_speed=c, tau_obs=c * 2.0,
                  meshes=[Mesh("wall", v, t, velocity=Velocity((0.0, -0.5, 0.0)), pivot=(0, 20, 0))])
    passes = render_image(scene, settings((33, 33)))
    s = passes["Depth"][16, 16, 0]
    # the wall is at 20 - 0.5 tau; light leaves it at tau_e and arrives at tau_obs = 20:
    # 20 - 0.5 tau_e = 20 - tau_e  ->  tau_e = 0, distance 20
    assert abs(s - 20.0) < 1e-4
    assert abs(passes["Emission Time"][16, 16, 0] - (2.0 - 20.0 / c)) < 1e-6
    assert np.all(passes["Emission Time"][..., 0] <= 2.0)


def test_lorentz_contraction_seen_by_an_orthographic_camera():
    """Parallel rays perpendicular to the motion arrive simultaneously: the front face shows L / gamma.

    Light from deeper points left earlier, so the trailing end face shows too (Terrell rotation):
    it adds beta * depth on the trailing side.  The bar is two objects of one assembly (same
    velocity, common pivot): they contract as one body.
    """
    left = box((-1.0, 0.0, 0.0), (2.0, 0.5, 0.5))
    right = box((1.0, 0.0, 0.0), (2.0, 0.5, 0.5))
    m = np.eye(4)
    m[:3, :3] = np.array([[1, 0, 0], [0, 0, 1], [0, -1, 0]]).T  # looking along +y, up = +z
    m[:3, 3] = (0.0, -10.0, 0.0)
    frame = np.array([[4.0, 1.0, -1.0], [4.0, -1.0, -1.0], [-4.0, -1.0, -1.0], [-4.0, 1.0, -1.0]])
    camera = Camera(matrix=m, kind="ORTHO", frame=frame, clip_start=0.0, clip_end=100.0)
    res = (801, 21)
    for pivot, expect_gap in (((0.0, 0.0, 0.0), False), (None, True)):
        meshes = [Mesh("left", *left, velocity=Velocity((0.8, 0, 0)), pivot=pivot or (-1.0, 0, 0)),
                  Mesh("right", *right, velocity=Velocity((0.8, 0, 0)), pivot=pivot or (1.0, 0, 0))]
        tau = 10.0 - 0.25  # light from the bar's front face (y = -0.25) emitted at tau = 0
        passes = render_image(Scene(camera=camera, meshes=meshes, tau_obs=tau), settings(res, film_transparent=True))
        row = passes["Combined"][10, :, 3] > 0.5
        xs = (np.flatnonzero(row) + 0.5) / res[0] * 8.0 - 4.0
        if not expect_gap:
            assert row[np.flatnonzero(row)[0]:np.flatnonzero(row)[-1] + 1].all()
            px = 8.0 / res[0]
            assert abs(xs.max() + px / 2 - 4.0 * 0.6 / 2) < px  # leading edge of the contracted front face
            assert abs(xs.min() - px / 2 - (-4.0 * 0.6 / 2 - 0.8 * 0.5)) < px  # trailing end face, depth 0.5
        else:  # separate pivots: each half contracts about its own centre
            assert not row[np.flatnonzero(row)[0]:np.flatnonzero(row)[-1] + 1].all()


@pytest.mark.parametrize("velocity", [Velocity((1.0, 0, 0)), Velocity((0.6, 0.8, 0.0)), Velocity((math.nan, 0, 0)),
                                      Velocity((math.inf, 0, 0)), Velocity((1, 0, 0), lorentz_factor=0.5)])
def test_bad_velocity_is_a_render_error_naming_the_object(velocity):
    v, t = box()
    scene = Scene(camera=look_at_camera((0, -5, 0), (0, 0, 0)), meshes=[Mesh("Rocket", v, t, velocity=velocity)])
    with pytest.raises(RenderError, match="Rocket"):
        render_image(scene, settings((8, 8)))


def test_bad_light_velocity_names_the_light():
    scene = Scene(camera=look_at_camera((0, -5, 0), (0, 0, 0)),
                  lights=[Light("Beacon", "POINT", (0, 0, 3), velocity=Velocity((0, 0, 2.0)))])
    with pytest.raises(RenderError, match="Beacon"):
        render_image(scene, settings((8, 8)))


def test_threads_tiles_and_regions_give_identical_pixels():
    scene = ball_scene(0.7)
    base = render_image(scene, settings((40, 30), samples=4, tile_size=64, threads=1))
    tiled = render_image(scene, settings((40, 30), samples=4, tile_size=7, threads=2))
    for name in base:
        assert np.array_equal(base[name], tiled[name]), name
    region = render_image(scene, settings((40, 30), samples=4, region=(5, 3, 29, 17), tile_size=16))
    for name in base:
        assert np.array_equal(base[name][3:17, 5:29], region[name][3:17, 5:29]), name


@pytest.mark.parametrize("mode", ["FACTOR", "OFF"])
def test_whole_image_measurements_make_regions_match(mode):
    """The Factor display's auto range and the exposure normalisation are measured on the whole
    image, so a region renders exactly the pixels of the full render (no seams between regions)."""
    common = dict(samples=2, doppler_mode=mode, normalize_exposure=(mode == "OFF"), tile_size=16)
    full = render_image(ball_scene(0.8), settings((40, 30), **common))
    part = render_image(ball_scene(0.8), settings((40, 30), region=(20, 0, 40, 15), **common))
    assert np.array_equal(full["Combined"][0:15, 20:40], part["Combined"][0:15, 20:40])


def test_no_nan_and_positive_doppler_at_extreme_speed():
    scene = ball_scene(0.0)
    for mesh in scene.meshes:
        mesh.velocity = Velocity((0.3, -0.2, 0.1), lorentz_factor=1e8)
    passes = render_image(scene, settings((24, 24), samples=2))
    for name, data in passes.items():
        assert np.all(np.isfinite(data)), name
    hit = passes["Depth"][..., 0] < 1e10
    assert np.all(passes["Doppler"][..., 0][hit] > 0)
    assert np.all(passes["Combined"] >= 0)


def test_cancel_stops_rendering():
    scene = ball_scene(0.5)
    calls = []

    def stop():
        calls.append(1)
        return len(calls) > 3

    passes = render_image(scene, settings((64, 64), tile_size=8), should_stop=stop)
    assert np.count_nonzero(passes["Combined"][..., 3]) < 64 * 64


def test_clip_range_is_the_clip_depth_over_the_cosine_to_the_view_axis():
    """Clip distances are depths along the view axis: path lengths clip / cos(angle to the axis),
    whatever the scale of the camera's frame (a long lens puts it far from z = -1); a tile's
    pixel-centre grid gives the same rays as the same positions listed one by one."""
    camera = look_at_camera((1.0, -2.0, 0.5), (0.0, 3.0, 1.0), fov_half_tan=0.7, aspect=1.5)
    camera.frame = camera.frame * 3.5  # same view, image plane at z = -3.5
    camera.clip_start, camera.clip_end = 0.25, 40.0
    res = (12, 8)
    xs, ys = np.arange(3, 9) + 0.5, np.arange(2, 7) + 0.5
    px, py = np.tile(xs, len(ys)), np.repeat(ys, len(xs))
    origins, d, s_lo, s_hi, valid = primary_rays(camera, px, py, res)
    axis = -np.asarray(camera.matrix)[:3, 2]
    cosine = d @ axis
    np.testing.assert_allclose(s_lo, 0.25 / cosine, rtol=1e-14)
    np.testing.assert_allclose(s_hi, 40.0 / cosine, rtol=1e-14)
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1.0, rtol=1e-15)
    grid = primary_rays(camera, xs, ys, res, grid=True)
    for flat, tiled in zip((origins, d, s_lo, s_hi, valid), grid):
        np.testing.assert_array_equal(flat, tiled)


@pytest.mark.parametrize("levels", [1, -3])
def test_factor_display_refuses_a_single_grey_level(levels):
    """0 levels is the continuous display and N >= 2 evenly spaced greys; one level (or fewer) would
    paint every hit one grey, so the Factor display refuses it; other modes ignore the setting."""
    v, t = quad((0.0, 10.0, 0.0), (20.0, 20.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)),
                  meshes=[Mesh("wall", v, t, velocity=Velocity((0.8, 0.0, 0.0)), pivot=(0, 10, 0))])
    with pytest.raises(RenderError, match=f"Levels must be 0 \\(continuous\\) or at least 2, not {levels}"):
        render_image(scene, settings((8, 8), doppler_mode="FACTOR", doppler_levels=levels))
    rgb = render_image(scene, settings((8, 8), doppler_levels=levels))["Combined"]
    np.testing.assert_array_equal(rgb, render_image(scene, settings((8, 8)))["Combined"])


def test_only_the_requested_passes_are_filled_and_they_match_a_full_render():
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    scene = Scene(camera=look_at_camera((0, -4, 0), (0, 0, 0)),
                  meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.0, 0.0)))])
    full = render_image(scene, settings((16, 16)))
    some = render_image(scene, settings((16, 16), passes=("Depth", "Doppler")))
    assert set(some) == {"Combined", "Depth", "Doppler"}
    for name in some:
        np.testing.assert_array_equal(some[name], full[name])
    with pytest.raises(RenderError, match="unknown passes"):
        render_image(scene, settings((16, 16), passes=("Vector",)))


def test_blas_runs_on_one_thread_while_tiles_render_and_is_restored_after():
    """numpy's OpenBLAS would start its own threads in every thin matrix product, and two render
    threads doing so oversubscribe the cores (see core/blas.py)."""
    import sys

    from restframe_addon.core import blas
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tiles

    controls = blas._openblas()
    if controls is None:
        assert not sys.platform.startswith("linux"), "numpy's OpenBLAS was not found"
        pytest.skip("no OpenBLAS in this numpy")
    set_threads, get_threads = controls
    before = get_threads()
    v, t = quad((0.0, 5.0, 0.0), (4.0, 4.0), normal_axis=1)
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)), meshes=[Mesh("wall", v, t)])
    seen = []
    for tile in render_tiles(prepare(scene, settings((8, 8), tile_size=4, threads=2))):
        seen.append(get_threads())
    assert seen == [1, 1, 1, 1]
    assert get_threads() == before


def test_batches_bound_the_colour_values_and_rays_whatever_the_tile_and_cover_each_sample_once():
    from restframe_addon.core.render import _BATCH_VALUES, _MAX_VALUES, _batches

    for n, samples, channels in ((65536, 1, 32), (65536, 4, 3), (65536, 8, 3), (4096, 16, 64), (10, 7, 3)):
        seen = np.zeros((n, samples), dtype=int)
        for part, first, count in _batches(n, samples, channels):
            assert (part.stop - part.start) * count * channels <= max(_MAX_VALUES, channels)
            assert (part.stop - part.start) * count * channels <= max(_BATCH_VALUES, count * channels)
            seen[part, first:first + count] += 1
        assert np.all(seen == 1)


def test_the_batch_size_changes_no_pixel(monkeypatch):
    """``_BATCH_VALUES`` splits a group of samples by pixels: each pixel's samples are summed in the
    same groups (``_MAX_VALUES``'), so the image is the same bits whatever it is."""
    from restframe_addon.core import render

    def groups():
        by_pixel = {}
        for part, first, count in render._batches(4096, 16, 3):
            for pixel in range(part.start, part.stop):
                by_pixel.setdefault(pixel, []).append((first, count))
        return by_pixel, sum(1 for _ in render._batches(4096, 16, 3))

    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    scene = Scene(camera=look_at_camera((0, -4, 0), (0, 0, 0)), lights=[Light("lamp", "POINT", (1, -3, 2), power=500.0)],
                  meshes=[Mesh("ball", v, t, velocity=Velocity((0.6, 0.0, 0.0))),
                          Mesh("floor", *quad((0.0, 0.0, -1.2), (6.0, 6.0), normal_axis=2))])
    rendered, grouped = [], []
    for values in (1 << 20, 120):  # a batch of every sample of a tile, then of eight pixels' 5 samples
        monkeypatch.setattr(render, "_BATCH_VALUES", values)
        rendered.append(render_image(scene, settings((32, 24), tile_size=16, samples=5)))
        grouped.append(groups())
    assert grouped[0][0] == grouped[1][0] and grouped[1][1] > grouped[0][1]  # the same groups, more batches
    for name, values in rendered[0].items():
        np.testing.assert_array_equal(values, rendered[1][name], err_msg=name)
    assert rendered[0]["Combined"][..., :3].max() > 0


def test_a_tile_larger_than_one_batch_renders_as_small_tiles_do():
    """Spectral mode with many wavelengths: one sample of a 64x64 tile is more colour values than
    a batch may hold, so the tile is rendered in pixel parts -- with the same result."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    scene = Scene(camera=look_at_camera((0, -4, 0), (0, 0, 0)), lights=[Light("lamp", "POINT", (1, -3, 2), power=500.0)],
                  meshes=[Mesh("ball", v, t, velocity=Velocity((0.6, 0.0, 0.0)))])
    common = dict(doppler_mode="SPECTRAL", spectral_samples=64)
    whole = render_image(scene, settings((64, 64), tile_size=64, **common))
    small = render_image(scene, settings((64, 64), tile_size=16, **common))
    np.testing.assert_array_equal(whole["Combined"], small["Combined"])
    assert whole["Combined"][..., :3].max() > 0


def test_passes_are_the_float64_values_of_the_centre_rays_rounded_once():
    """The passes are written straight into float32: each value is the float64 one of the
    pixel-centre ray's hit (independently traced here) rounded once; misses are the background's."""
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tile
    from restframe_addon.core.tracer import trace_nearest

    scene = ball_scene(0.6)
    res = (20, 16)
    prepared = prepare(scene, settings(res, passes=("Depth", "Doppler", "Emission Time")))
    rect = (0, 0, *res)
    tau, x, d, s_lo, s_hi = prepared.centre_rays(rect)
    hits = trace_nearest(prepared.frames, prepared.frames.camera, tau, x, d, s_lo, s_hi)
    hit = hits.frame >= 0
    assert 0 < hit.sum() < hit.size
    tile = render_tile(prepared, rect)
    expected = {"Depth": np.where(hit, hits.s, 1e10), "Doppler": np.where(hit, 1.0 / hits.w, 0.0),
                "Emission Time": np.where(hit, (tau - hits.s) / scene.light_speed, 0.0)}
    for name, values in expected.items():
        assert tile.passes[name].dtype == np.float32
        np.testing.assert_array_equal(tile.passes[name][..., 0], values.astype(np.float32).reshape(res[1], res[0]),
                                      err_msg=name)


def lone_ball_off_centre():
    """A small moving ball in one corner of a wide view, a coloured world: most tiles see nothing."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 0.6, 24, 12)
    ghost = Material("ghost", base_color=(0.8, 0.2, 0.1), emission=(0.5, 0.5, 0.0), alpha=0.5)
    return Scene(camera=look_at_camera((-2.0, -6.0, 1.0), (-2.0, 0.0, 1.0)), world_color=(0.1, 0.2, 0.3),
                 meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.2, 0.0)))], materials=[ghost])


@pytest.mark.parametrize("options", [
    dict(samples=1, passes=("Depth", "Doppler", "Emission Time", "Object Time", "Normal", "IndexOB")),
    dict(samples=3, doppler_mode="FACTOR", film_transparent=True, passes=("Depth", "Denoising Albedo")),
    dict(samples=2, doppler_mode="SPECTRAL", spectral_samples=8, normalize_exposure=True),
])
def test_tiles_that_see_nothing_are_not_traced_and_render_the_same(monkeypatch, options):
    """A tile whose rays' cone misses every frame's bounding cones is neither made nor traced
    (no tracer call), and renders the very pixels and passes of the full path."""
    from restframe_addon.core import prepared as prepared_module
    from restframe_addon.core import shading

    scene = lone_ball_off_centre()
    traced = []
    trace = shading.trace_nearest
    monkeypatch.setattr(shading, "trace_nearest", lambda *args, **kw: traced.append(len(args[4])) or trace(*args, **kw))
    quick = render_image(scene, settings((48, 40), tile_size=8, **options))
    quick_rays, traced[:] = sum(traced), []
    monkeypatch.setattr(prepared_module.PreparedScene, "each_misses_everything",
                        lambda self, rects, cache=None: [False] * len(rects))
    full = render_image(scene, settings((48, 40), tile_size=8, **options))
    assert quick_rays < 0.75 * sum(traced)  # (the exposure measurement traces a preview either way)
    assert 0.02 < (full["Depth"] < 1e9).mean() < 0.5
    for name in full:
        np.testing.assert_array_equal(quick[name], full[name], err_msg=name)


@pytest.mark.parametrize("threads", [1, 2])
def test_tiles_that_see_nothing_are_rendered_once_per_shape(threads):
    """The tiles of a render that see nothing share one set of read-only pass arrays per shape
    (rendered once), each the very bits of that tile rendered alone."""
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tile, render_tiles

    prepared = prepare(lone_ball_off_centre(), settings((44, 40), tile_size=8, threads=threads,
                                                        passes=("Depth", "Doppler", "Emission Time", "Object Time")))
    tiles = list(render_tiles(prepared))
    unseen = [tile for tile in tiles if prepared.misses_everything((tile.x0, tile.y0, tile.x1, tile.y1))]
    shapes = {(t.x1 - t.x0, t.y1 - t.y0) for t in unseen}
    assert len(shapes) == 2 and len(unseen) > 10 and len(unseen) < len(tiles)  # 8x8 tiles and the 4x8 ones at the edge
    arrays = {id(values) for tile in unseen for values in tile.passes.values()}
    assert len(arrays) <= threads * len(shapes) * len(unseen[0].passes)
    for tile in tiles:
        alone = render_tile(prepared, (tile.x0, tile.y0, tile.x1, tile.y1))
        assert tile.passes.keys() == alone.passes.keys()
        for name, values in alone.passes.items():
            np.testing.assert_array_equal(tile.passes[name], values, err_msg=name)
            assert tile.passes[name].dtype == values.dtype
    assert not any(values.flags.writeable for tile in unseen for values in tile.passes.values())


def test_tiles_that_see_something_are_dealt_first(monkeypatch):
    """The render threads take the tiles that see something first, then the short ones that see
    nothing (which even out the threads' ends), each tile once, all found in one pass (one thread: in their order, also found in one pass)."""
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import UnseenTiles, seen_first, tiles_in_threads

    prepared = prepare(lone_ball_off_centre(), settings((44, 40), tile_size=8, threads=2))
    rects = prepared.tiles()
    empty = [prepared.misses_everything(rect) for rect in rects]
    assert 0 < sum(empty) < len(rects) and empty[0] and not all(empty[:len(rects) - sum(empty)])  # not so already
    asked = []
    each = type(prepared).each_misses_everything
    monkeypatch.setattr(type(prepared), "each_misses_everything",
                        lambda self, found, cache=None: asked.append(len(found)) or each(self, found, cache))
    order = list(seen_first(UnseenTiles(prepared), rects))
    assert order == [r for r, e in zip(rects, empty) if not e] + [r for r, e in zip(rects, empty) if e]
    assert asked == [len(rects)]  # every tile's cone and cull at once, not one call per tile
    tiles = list(tiles_in_threads(prepared, rects, 2, lambda: False))
    assert sorted((t.x0, t.y0, t.x1, t.y1) for t in tiles) == sorted(rects)
    asked.clear()
    tiles = list(tiles_in_threads(prepared, rects, 1, lambda: False))
    assert [(t.x0, t.y0, t.x1, t.y1) for t in tiles] == rects  # one thread: in their order,
    assert asked == [len(rects)]  # and their emptiness found at once too


def _ball_over_floor() -> Scene:
    """A ball at 0.6c over a floor in sunlight, seen from above the floor: the cull tests' scene."""
    v, t = uv_sphere((0.0, 0.0, 0.0), 1.0, 24, 12)
    return Scene(camera=look_at_camera((0, -4, 0.5), (0, 0, 0)), lights=[Light("lamp", "SUN", (1, -3, 2), power=3.0)],
                 meshes=[Mesh("ball", v, t, velocity=Velocity((0.6, 0.0, 0.0))),
                         Mesh("floor", *quad((0.0, 0.0, -1.2), (6.0, 6.0), normal_axis=2))])


def _same_passes(once, each) -> None:
    for name, values in once.passes.items():
        np.testing.assert_array_equal(values, each.passes[name], err_msg=name)


def test_a_tiles_camera_rays_are_culled_once_for_all_its_samples(monkeypatch):
    """One sample a batch: the runs near the frames' body boxes are worked out once a tile (from
    bounds holding every sample's rays and the pixel-centre rays, ``CameraRays.run_bounds``), not
    once a batch and again for the pixel-centre rays; the same bits as culling each batch's own rays."""
    from restframe_addon.core import render, tracer
    from restframe_addon.core.camera import CameraRays
    from restframe_addon.core.prepared import prepare

    scene = _ball_over_floor()
    monkeypatch.setattr(render, "_MAX_VALUES", 32 * 32 * 3)  # one sample a batch
    prepared = prepare(scene, settings((32, 32), tile_size=32, samples=4))
    culls = []
    near = tracer._runs_near_bodies
    monkeypatch.setattr(tracer, "_runs_near_bodies", lambda *args: culls.append(1) or near(*args))
    once = render.render_tile(prepared, prepared.region)
    assert len(culls) == 1  # the tile's, for the pixel-centre rays and its 4 batches
    monkeypatch.setattr(CameraRays, "run_bounds", lambda *args: None)
    culls.clear()
    each = render.render_tile(prepared, prepared.region)
    assert len(culls) == 5
    _same_passes(once, each)
    sky = np.isclose(once.passes["Combined"][..., :3], once.passes["Combined"][-1, -1, :3]).all(axis=-1)
    assert 0.1 < sky.mean() < 0.9  # (runs of rays that miss everything, and rays that hit)


def test_a_small_tiles_batches_of_several_samples_a_pixel_are_culled_once_too(monkeypatch):
    """Two samples a pixel a batch (a divisor of ``RunBounds.RUN``): each run of rays is that of 8
    pixels, and its bounds (``CameraRays.run_bounds`` of 8-pixel runs) cull both batches once; the
    same bits as culling each batch's own rays."""
    from restframe_addon.core import render, tracer
    from restframe_addon.core.camera import CameraRays
    from restframe_addon.core.prepared import prepare

    scene = _ball_over_floor()
    monkeypatch.setattr(render, "_MAX_VALUES", 32 * 32 * 3 * 2)  # two samples a batch
    monkeypatch.setattr(render, "_BATCH_VALUES", 32 * 32 * 3 * 2)
    prepared = prepare(scene, settings((32, 32), tile_size=32, samples=4))
    assert [count for _, _, count in render._batches(32 * 32, 4, 3)] == [2, 2]
    culls, runs = [], []
    near = tracer._runs_near_bodies
    monkeypatch.setattr(tracer, "_runs_near_bodies", lambda *args: culls.append(1) or near(*args))
    run_bounds = CameraRays.run_bounds
    monkeypatch.setattr(CameraRays, "run_bounds", lambda self, rect, part, run: runs.append(run) or run_bounds(
        self, rect, part, run))
    once = render.render_tile(prepared, prepared.region)
    assert len(culls) == 2 and runs == [16, 8]  # the pixel-centre rays', then the tile's for its 2 batches
    monkeypatch.setattr(CameraRays, "run_bounds", lambda *args: None)
    culls.clear()
    each = render.render_tile(prepared, prepared.region)
    assert len(culls) == 3
    _same_passes(once, each)

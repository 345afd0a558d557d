"""Depth of field: the aperture samples, the thin-lens rays and the circle of confusion they render,
at rest and seen from a camera at 0.9c (the aperture in the camera's rest frame)."""

import math
from dataclasses import replace

import numpy as np
import pytest
from measures import streak_ends
from shapes import look_at_camera, uv_sphere

from restframe_addon.core import lens, sampling
from restframe_addon.core.camera import CameraRays
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Camera, Material, Mesh, RenderSettings, Scene, Velocity

N = 200_000
KEYS = (np.full(N, 7, dtype=np.int64), np.arange(N, dtype=np.int64), N)  # one pixel's N samples


def polygon_harmonic(x, y, corners):
    """Mean of exp(i corners phi): its phase points at a corner of an N-fold symmetric cloud."""
    return np.mean(np.exp(1j * corners * np.arctan2(y, x)))


@pytest.mark.parametrize("corners, rotation", [(3, 0.0), (6, 0.4), (9, -1.0)])
def test_polygon_samples_fill_the_regular_polygon_uniformly_with_cycles_corners(corners, rotation):
    u1, u2 = np.random.default_rng(1).random((2, N))
    x, y = lens.regular_polygon(u1, u2, corners, rotation)
    # inside every side: sides face rotation + 2 pi j / N, at the apothem cos(pi / N)
    sides = rotation + 2 * np.pi * np.arange(corners) / corners
    reach = np.outer(x, np.cos(sides)) + np.outer(y, np.sin(sides))
    apothem = math.cos(math.pi / corners)
    assert reach.max() <= apothem + 1e-12
    assert reach.max() > apothem - 1e-3  # and out to the sides
    # uniform: the polar second moment of a regular N-gon inscribed in the unit circle, and mean 0
    assert np.mean(x * x + y * y) == pytest.approx((1 + 2 * apothem**2) / 6, rel=5e-3)
    assert abs(np.mean(x)) < 5e-3 and abs(np.mean(y)) < 5e-3
    # corners at rotation + (2 j + 1) pi / N
    phase = np.angle(polygon_harmonic(x, y, corners))
    corner = rotation + math.pi / corners
    assert abs(np.angle(np.exp(1j * (phase - corners * corner)))) / corners < 0.005  # radians, of pi / N apart


def test_disc_samples_are_uniform_in_the_unit_disc():
    u1, u2 = np.random.default_rng(2).random((2, N))
    x, y = lens.concentric_disc(u1, u2)
    r2 = x * x + y * y
    assert r2.max() <= 1.0 + 1e-12
    # uniform in area: r^2 is uniform on [0, 1]
    counts, _ = np.histogram(r2, bins=10, range=(0.0, 1.0))
    assert np.all(np.abs(counts / (N / 10) - 1.0) < 0.03)
    assert abs(np.mean(np.cos(np.arctan2(y, x)))) < 5e-3


def test_ratio_squeezes_the_aperture_across():
    camera = Camera(matrix=np.eye(4), aperture_radius=0.3, aperture_ratio=2.0)
    x, y = lens.aperture_offsets(camera, *KEYS)
    assert np.abs(x).max() == pytest.approx(0.15, rel=1e-3)
    assert np.abs(y).max() == pytest.approx(0.3, rel=1e-3)
    assert np.mean(x * x) / np.mean(y * y) == pytest.approx(0.25, rel=0.02)


def test_aperture_radius_from_the_f_stop_as_cycles():
    assert lens.aperture_radius(2.8, 50.0) == pytest.approx(0.05 / 5.6)
    assert lens.aperture_radius(2.0, None) == pytest.approx(0.25)


def tilted_camera(kind, **lens_settings):
    """A camera somewhere, turned off the axes, with a thin lens."""
    camera = look_at_camera((1.0, -2.0, 0.5), (3.0, 6.0, 2.0), fov_half_tan=0.4, aspect=1.5)
    extra = {}
    if kind == "PANO":
        extra = dict(panorama_type="FISHEYE_EQUIDISTANT", fisheye_fov=math.radians(200))
    return replace(camera, kind=kind, **extra, **lens_settings)


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO", "PANO"])
def test_lens_rays_of_one_image_point_meet_on_the_focus_and_leave_the_aperture(kind):
    """Every sample of an image point leaves the aperture (across the view axis; across the ray for
    panoramas) and passes through the pinhole ray's point at the focus distance (depth along the
    view axis; distance for panoramas); the clip range stays the pinhole ray's (Cycles)."""
    radius, focus = 0.25, 7.0
    camera = tilted_camera(kind, aperture_radius=radius, focus_distance=focus, aperture_blades=5)
    rays = CameraRays(camera, (30, 20))
    n = 4000
    px, py = np.full(n, 21.3), np.full(n, 4.7)  # one image point, many samples
    keys = (np.full(n, 3, dtype=np.int64), np.arange(n, dtype=np.int64), n)
    o0, d0, lo0, hi0, _ = rays(px[:1], py[:1])
    origins, directions, lo, hi, valid = rays(px, py, keys=keys)
    assert valid.all()
    forward = -np.asarray(camera.matrix)[:3, 2]
    depth_per_length = 1.0 if kind == "PANO" else float(d0[0] @ forward)
    target = o0[0] + d0[0] * focus / depth_per_length
    to_target = target - origins
    along = np.einsum("ij,ij->i", to_target, directions)
    miss = np.linalg.norm(to_target - along[:, None] * directions, axis=1)
    assert miss.max() < 1e-9 * focus
    offset = origins - o0[0]
    normal = d0[0] if kind == "PANO" else forward
    assert np.abs(offset @ normal).max() < 1e-12
    assert np.linalg.norm(offset, axis=1).max() <= radius * (1 + 1e-12)
    assert np.linalg.norm(offset, axis=1).max() > 0.9 * radius
    if kind == "ORTHO":  # Cycles: starts at the near clip depth, keeps the clip length
        assert np.allclose(lo * (directions @ forward), camera.clip_start)
        assert np.allclose(hi - lo, camera.clip_end - camera.clip_start)
    else:
        assert np.all(lo == lo0[0]) and np.all(hi == hi0[0])


@pytest.mark.parametrize("kind", ["PERSP", "ORTHO", "PANO"])
def test_without_aperture_the_keys_change_nothing(kind):
    rays = CameraRays(tilted_camera(kind), (30, 20))
    px, py = np.array([1.5, 17.25, 29.0]), np.array([0.5, 10.0, 19.75])
    keys = (np.arange(3, dtype=np.int64), np.zeros(3, dtype=np.int64), 1)
    for plain, keyed in zip(rays(px, py), rays(px, py, keys=keys)):
        assert np.array_equal(plain, keyed)


# ---------------------------------------------------------------------- rendered circles of confusion
RES = 61
FOV_HALF_TAN = 0.1
FOCAL_PIXELS = 0.5 * RES / FOV_HALF_TAN  # image-plane units per unit of tan(angle) across, in pixels


def spot_image(camera, centre, radius=0.1, samples=256):
    """Combined (red) of a small emissive sphere (at rest in S) on black."""
    v, t = uv_sphere(centre, radius, 32, 16)
    scene = Scene(camera=camera, meshes=[Mesh("emitter", v, t)],
                  materials=[Material(base_color=(0.0, 0.0, 0.0), emission=(1.0, 1.0, 1.0))], world_color=(0, 0, 0))
    out = render_image(scene, RenderSettings(resolution=(RES, RES), samples=samples, threads=1, passes=()))
    return out["Combined"][..., 0].astype(np.float64)


def spot_moments(image):
    """(flux, centroid x, centroid y, mean squared distance from the centroid) in pixels."""
    h, w = image.shape
    y, x = np.mgrid[0:h, 0:w] + 0.5
    flux = image.sum()
    cx, cy = (image * x).sum() / flux, (image * y).sum() / flux
    return flux, cx, cy, (image * ((x - cx) ** 2 + (y - cy) ** 2)).sum() / flux


def blur_radius(pinhole, with_lens, blades):
    """Radius (pixels) of the aperture's image that the lens convolved the pinhole image with:
    the mean squared radius of a uniform disc is R^2 / 2, of a regular N-gon of circumradius R
    R^2 (1 + 2 cos^2(pi/N)) / 6; convolution adds mean squared radii."""
    spread = spot_moments(with_lens)[3] - spot_moments(pinhole)[3]
    k = 0.5 if blades < 3 else (1 + 2 * math.cos(math.pi / blades) ** 2) / 6
    return math.sqrt(spread / k)


@pytest.mark.parametrize("blades, depth", [(0, 10.0), (6, 10.0), (0, 3.0)])
def test_circle_of_confusion_is_the_thin_lens_one(blades, depth):
    """A point at depth z seen through a lens of aperture radius A focused at f blurs into the
    aperture's shape of radius A |1/f - 1/z| (image-plane units at unit distance): behind and in
    front of the focus."""
    aperture, focus = 0.4, 5.0
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=FOV_HALF_TAN)
    with_lens = replace(camera, aperture_radius=aperture, focus_distance=focus, aperture_blades=blades)
    pinhole = spot_image(camera, (0.0, depth, 0.0), radius=0.01 * depth)
    blurred = spot_image(with_lens, (0.0, depth, 0.0), radius=0.01 * depth)
    expected = aperture * abs(1 / focus - 1 / depth) * FOCAL_PIXELS
    assert blur_radius(pinhole, blurred, blades) == pytest.approx(expected, rel=0.01)
    assert spot_moments(blurred)[0] == pytest.approx(spot_moments(pinhole)[0], rel=0.03)  # same light


def test_the_plane_of_focus_stays_sharp():
    camera = look_at_camera((0, 0, 0), (0.3, 1, 0.1), fov_half_tan=FOV_HALF_TAN)
    with_lens = replace(camera, aperture_radius=0.4, focus_distance=5.0, aperture_blades=6)
    right, up, back = np.asarray(camera.matrix)[:3, :3].T
    centre = 5.0 * -back + 0.2 * right - 0.15 * up  # depth 5 along the view axis, off it
    pinhole, sharp = spot_image(camera, centre), spot_image(with_lens, centre)
    assert np.abs(sharp - pinhole).max() < 0.05 * pinhole.max()
    assert spot_moments(sharp)[3] == pytest.approx(spot_moments(pinhole)[3], rel=0.02)


def test_tiles_regions_and_threads_do_not_change_lens_and_shutter_samples():
    camera = replace(look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.3), aperture_radius=0.3,
                     focus_distance=4.0, aperture_blades=7, aperture_rotation=0.2, shutter_interval=(-1.0, 0.5),
                     rolling_shutter_type="TOP", rolling_shutter_duration=0.3)
    centre = (4.2, 8.0, 0.1)  # at 0.5c along x: seen near the axis at time 0 (c = 1 unit/s)
    v, t = uv_sphere(centre, 0.6, 24, 12)
    scene = Scene(camera=camera, meshes=[Mesh("ball", v, t, velocity=Velocity((0.5, 0.0, 0.0)), pivot=centre)],
                  materials=[Material(emission=(0.5, 1.0, 2.0))], world_color=(0.1, 0.1, 0.1), light_speed=1.0)
    base = dict(resolution=(23, 17), samples=6, passes=())
    whole = render_image(scene, RenderSettings(**base, threads=1))["Combined"]
    tiled = render_image(scene, RenderSettings(**base, threads=2, tile_size=5))["Combined"]
    region = render_image(scene, RenderSettings(**base, threads=1, region=(4, 3, 19, 11)))["Combined"]
    assert np.array_equal(whole, tiled)
    assert np.array_equal(whole[3:11, 4:19], region[3:11, 4:19])
    one_sample = render_image(scene, RenderSettings(**{**base, "samples": 1}, threads=1))["Combined"]
    pinhole = render_image(replace(scene, camera=replace(camera, aperture_radius=0.0)),
                           RenderSettings(**{**base, "samples": 1}, threads=1))["Combined"]
    assert not np.array_equal(one_sample, pinhole)  # one sample per pixel goes through the lens too
    instant = render_image(replace(scene, camera=replace(camera, shutter_interval=None)),
                           RenderSettings(**base, threads=1))["Combined"]
    assert not np.array_equal(whole, instant)  # and the shutter blurs the moving ball


# ---------------------------------------------------------------------- a camera at 0.9c
BETA = 0.9
GAMMA = 1.0 / math.sqrt((1 - BETA) * (1 + BETA))


def emitter_seen_on_axis_at(depth):
    """World (S) position of a static point whose light reaches the camera (at the origin event,
    moving at 0.9c along x, looking along +y in its rest frame) from camera-frame distance
    ``depth`` straight along the view axis: the camera-frame emission event (tau' = -depth,
    x' = depth y) boosted back to S by hand."""
    tau_c, x_c = -depth, np.array([0.0, depth, 0.0])
    beta = np.array([BETA, 0.0, 0.0])
    # the inverse boost x = x' + (k beta.x' + gamma tau') beta, with beta . x' = 0 here
    return x_c + GAMMA * tau_c * beta


def test_moving_camera_focuses_in_its_own_rest_frame():
    """At 0.9c across the view, the aperture at one camera-frame time: a static emitter whose light
    left from the camera-frame focus distance on the axis is as sharp as through a pinhole, at
    the image centre (where aberration puts it, 64 degrees off its S direction); one at twice the
    distance blurs by the thin-lens radius of its camera-frame distance."""
    aperture, focus = 0.2, 5.0
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=FOV_HALF_TAN, velocity=Velocity((BETA, 0, 0)))
    with_lens = replace(camera, aperture_radius=aperture, focus_distance=focus)
    in_focus = emitter_seen_on_axis_at(focus)
    assert math.degrees(math.atan2(-in_focus[0], in_focus[1])) == pytest.approx(64.16, abs=0.01)
    pinhole = spot_image(camera, in_focus, radius=0.05)
    sharp = spot_image(with_lens, in_focus, radius=0.05)
    _, cx, cy, spread = spot_moments(pinhole)
    assert abs(cx - RES / 2) < 0.05 and abs(cy - RES / 2) < 0.05
    # the residual is the emitter's second-order drift while the rays from the aperture's rim
    # pass the focus (0.9 A^2 / 2f = 0.0036, 0.2 px); a lens in S would put it 2.3x farther
    assert spot_moments(sharp)[3] - spread < 0.1
    far = emitter_seen_on_axis_at(2 * focus)
    blurred = spot_image(with_lens, far, radius=0.1)
    expected = aperture * (1 / focus - 1 / (2 * focus)) * FOCAL_PIXELS
    assert blur_radius(spot_image(camera, far, radius=0.1), blurred, 0) == pytest.approx(expected, rel=0.02)


# ---------------------------------------------------------------------- shutter
def test_shutter_times_follow_the_shutter_curve_density():
    """Sampled fractions of the shutter interval have the curve's density (linear between its
    points): bin counts against the curve's integral over each bin."""
    curve = np.array([0.0, 1.0, 3.0, 3.0, 0.5, 2.0, 0.0])
    xi = np.random.default_rng(3).random(N)
    fractions = lens.shutter_fractions(xi, curve)
    assert fractions.min() >= 0.0 and fractions.max() <= 1.0
    edges = np.linspace(0.0, 1.0, 49)
    fine = np.linspace(0.0, 1.0, 100_001)
    density = np.interp(fine, np.linspace(0.0, 1.0, len(curve)), curve)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (density[1:] + density[:-1]) * np.diff(fine))])
    expected = np.diff(np.interp(edges, fine, cdf / cdf[-1])) * N
    counts, _ = np.histogram(fractions, bins=edges)
    assert np.all(np.abs(counts - expected) < 4.5 * np.sqrt(expected) + 1)
    # exact inverse: the distribution function of the sampled fraction is xi itself
    np.testing.assert_allclose(np.interp(fractions, fine, cdf / cdf[-1]), xi, atol=1e-6)


def test_flat_shutter_is_uniform_over_the_interval():
    camera = Camera(matrix=np.eye(4), shutter_interval=(-0.02, 0.03))
    times = lens.shutter_times(camera, *KEYS, (4, 4))
    assert times.min() >= -0.02 and times.max() <= 0.03
    counts, _ = np.histogram(times, bins=10, range=(-0.02, 0.03))
    assert np.all(np.abs(counts / (N / 10) - 1.0) < 0.03)


@pytest.mark.parametrize("duration", [0.0, 0.1, 0.6, 1.0])
def test_rolling_shutter_exposes_each_row_in_its_own_window(duration):
    """Cycles' TOP rolling shutter: row y (of H, counted from the bottom) is exposed over the
    fractions [(1 - y/H)(1 - d), (1 - y/H)(1 - d) + d] of the shutter interval, d the duration."""
    width, height = 5, 8
    camera = Camera(matrix=np.eye(4), shutter_interval=(0.0, 2.0), rolling_shutter_type="TOP",
                    rolling_shutter_duration=duration)
    for row in (0, 3, height - 1):
        pixel = np.full(20_000, row * width + 2, dtype=np.int64)
        times = lens.shutter_times(camera, pixel, np.arange(len(pixel)), len(pixel), (width, height)) / 2.0
        opens = (1.0 - row / height) * (1.0 - duration)
        assert times.min() >= opens - 1e-12 and times.max() <= opens + duration + 1e-12
        assert np.mean(times) == pytest.approx(opens + duration / 2, abs=0.01 * max(duration, 0.01))
        if duration:
            assert times.max() - times.min() > 0.99 * duration


@pytest.mark.parametrize("problem, message", [
    (dict(shutter_interval=(0.1, -0.1)), "Cam: the shutter interval"),
    (dict(shutter_interval=(0.0, 0.1), shutter_curve=np.zeros(5)), "shutter curve is zero everywhere"),
    (dict(shutter_interval=(0.0, 0.1), rolling_shutter_type="BOTTOM"), "Cam: rolling shutter type"),
    (dict(aperture_radius=-0.1), "Cam: the aperture radius"),
    (dict(aperture_radius=0.1, focus_distance=0.0), "Cam: depth of field needs"),
    (dict(aperture_radius=0.1, aperture_ratio=0.0), "Cam: depth of field needs"),
])
def test_bad_lens_and_shutter_settings_are_render_errors(problem, message):
    from restframe_addon.core.render import RenderError
    scene = Scene(camera=replace(look_at_camera((0, 0, 0), (0, 1, 0)), name="Cam", **problem))
    with pytest.raises(RenderError, match=message):
        render_image(scene, RenderSettings(resolution=(4, 4), threads=1))


# ---------------------------------------------------------------------- motion blur at 0.9c
STREAK_RES = (161, 15)
PATH_DISTANCE, PATH_START = 10.0, 9.0  # the emitter's path: y = 10, through x = 9 at camera time 0


def apparent_x(t):
    """Where on its path (x, at y = PATH_DISTANCE) a point moving at 0.9c along x, at x = PATH_START
    at time 0, is seen from the origin at time t: the retarded position x_e = a - beta u, with
    a = x(t) and u = t - t_e the light's travel time, the root of u^2 = (a - beta u)^2 + D^2."""
    a = PATH_START + BETA * t
    u = (-a * BETA + np.sqrt(a * a + (1 - BETA * BETA) * PATH_DISTANCE**2)) / (1 - BETA * BETA)
    return a - BETA * u


@pytest.mark.parametrize("mover", ["emitter", "camera"])
def test_streak_of_an_emitter_crossing_at_0_9c_is_its_apparent_motion_over_the_shutter(mover):
    """A shutter open for 8 s of the camera's clock (c = 1 unit/s): the streak of a small emitter
    crossing the view at 0.9c runs between its apparent (retarded) positions at the shutter's
    opening and closing (apparent speed v / (1 - beta cos theta): twice as fast at the approaching
    end as at the receding one).  The same seen from a camera moving at -0.9c past a static emitter (placed gamma times
    farther out, where its camera-frame path is the same): the shutter times are the camera's
    proper times, so the streak is the same."""
    width, height = STREAK_RES
    opens, closes = -4.0, 4.0
    camera = replace(look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.5, aspect=width / height),
                     shutter_interval=(opens, closes))
    if mover == "emitter":
        centre, velocity = (PATH_START, PATH_DISTANCE, 0.0), Velocity((BETA, 0.0, 0.0))
    else:  # at camera time 0 the static emitter sits, contracted by gamma, at PATH_START
        centre, velocity = (PATH_START * GAMMA, PATH_DISTANCE, 0.0), Velocity()
        camera = replace(camera, velocity=Velocity((-BETA, 0.0, 0.0)))
    v, t = uv_sphere(centre, 0.1, 24, 12)
    scene = Scene(camera=camera, meshes=[Mesh("emitter", v, t, velocity=velocity, pivot=centre)],
                  materials=[Material(base_color=(0, 0, 0), emission=(1, 1, 1))], world_color=(0, 0, 0),
                  light_speed=1.0)
    image = render_image(scene, RenderSettings(resolution=STREAK_RES, samples=1024, threads=1, passes=(),
                                               searchlight=False))["Combined"][..., 0]
    seen = apparent_x(np.array([opens, closes]))
    expected = (seen / PATH_DISTANCE / 0.5 + 1.0) * width / 2  # columns (the image spans tan = +-0.5)
    measured = streak_ends(image.sum(axis=0).astype(np.float64))
    np.testing.assert_allclose(measured, expected, atol=1.0)
    assert measured[1] - measured[0] == pytest.approx(expected[1] - expected[0], rel=0.01)


def retarded_position(start, velocity, t):
    """Where a point at ``start`` at time 0, moving with ``velocity`` (units of c), is seen from the
    origin at time t: the root t_e <= t of |start + velocity t_e|^2 = (t - t_e)^2."""
    start, velocity = np.asarray(start, dtype=float), np.asarray(velocity, dtype=float)
    a, b, c = velocity @ velocity - 1.0, 2.0 * (start @ velocity + t), start @ start - t * t
    roots = (-b + np.array([1.0, -1.0]) * math.sqrt(b * b - 4.0 * a * c)) / (2.0 * a)
    return start + velocity * roots[roots <= t].max()


def test_an_approaching_emitter_streaks_superluminally_as_its_retarded_positions():
    """An emitter at 0.9c, 25 degrees off head-on toward the camera, seen at the image centre 20
    units away at camera time 0: over a 3 s shutter its streak runs between its retarded positions
    at the shutter's ends, an apparent transverse speed of about 2c (beta sin / (1 - beta cos))."""
    width, height = STREAK_RES
    opens, closes = -1.5, 1.5
    angle = math.radians(25.0)
    velocity = BETA * np.array([math.sin(angle), -math.cos(angle), 0.0])
    start = np.array([0.0, 20.0, 0.0]) + 20.0 * velocity  # there at time -20: seen at the centre at 0
    camera = replace(look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.5, aspect=width / height),
                     shutter_interval=(opens, closes))
    v, t = uv_sphere(start, 0.1, 24, 12)
    scene = Scene(camera=camera, meshes=[Mesh("emitter", v, t, velocity=Velocity(tuple(velocity)), pivot=tuple(start))],
                  materials=[Material(base_color=(0, 0, 0), emission=(1, 1, 1))], world_color=(0, 0, 0),
                  light_speed=1.0)
    image = render_image(scene, RenderSettings(resolution=STREAK_RES, samples=1024, threads=1, passes=(),
                                               searchlight=False))["Combined"][..., 0]
    seen = np.array([retarded_position(start, velocity, t) for t in (opens, closes)])
    expected = (seen[:, 0] / seen[:, 1] / 0.5 + 1.0) * width / 2
    measured = streak_ends(image.sum(axis=0).astype(np.float64))
    np.testing.assert_allclose(measured, expected, atol=1.0)
    transverse_speed = (seen[1, 0] - seen[0, 0]) / (closes - opens)
    assert transverse_speed > 1.9  # faster than light across the view


@pytest.mark.parametrize("cells", [1, 2, 3, 7, 16, 100, 1024, 1025])
def test_shuffled_strata_are_a_permutation_per_pixel_unrelated_to_the_pixel_strata(cells):
    """Each pixel's samples 0..cells-1 visit every stratum once, in an order of their own per
    dimension: neither the pixel jitter's strata nor another dimension's predict it."""
    pixels = np.arange(50, dtype=np.int64)
    pixel, sample = np.repeat(pixels, cells), np.tile(np.arange(cells, dtype=np.int64), len(pixels))
    lens_cells = sampling.shuffled_strata(pixel, sample, cells, lens.LENS_DIMENSION).reshape(len(pixels), cells)
    assert np.all(np.sort(lens_cells, axis=1) == np.arange(cells))
    if cells >= 100:
        jitter_cells = sampling.strata(pixel, sample, cells, 0).reshape(len(pixels), cells)
        other = sampling.shuffled_strata(pixel, sample, cells, lens.SHUTTER_DIMENSION).reshape(len(pixels), cells)
        for a, b in ((lens_cells, jitter_cells), (lens_cells, other)):
            r = np.array([np.corrcoef(x, y)[0, 1] for x, y in zip(a, b)])
            assert np.abs(r).max() < 4.5 / math.sqrt(cells)  # as uncorrelated as random orders
        # and the first differences are not one fixed step (unlike a linear order)
        assert len(np.unique(np.diff(lens_cells[0]) % cells)) > cells // 4


def test_a_lens_and_a_rolling_shutter_through_every_code_path_give_the_same_bits_in_any_split():
    """The prepared-scene test's busy scene (moving, spinning, animated, glass, mirror, three kinds of
    lamps) seen through a moving camera's hexagonal lens and rolling shutter: odd tiles, two threads
    and another process render the same bits as render_image."""
    import multiprocessing
    from concurrent.futures import ProcessPoolExecutor

    from test_prepared import assemble, assert_same_passes, busy_scene

    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.render import render_tile, render_tiles

    scene = busy_scene(Velocity((0.0, 0.4, 0.0)))
    scene = replace(scene, camera=replace(scene.camera, aperture_radius=0.2, focus_distance=7.0, aperture_blades=6,
                                          shutter_interval=(-1.5, 0.5), shutter_curve=np.array([0.2, 1.0, 0.4]),
                                          rolling_shutter_type="TOP", rolling_shutter_duration=0.4))
    settings = RenderSettings(resolution=(24, 18), threads=1, samples=3, tile_size=16)
    whole = render_image(scene, settings)
    prepared = prepare(scene, settings)
    rects = [(x, y, min(x + 7, 24), min(y + 5, 18)) for y in range(0, 18, 5) for x in range(0, 24, 7)]
    assert_same_passes(assemble(prepared, [render_tile(prepared, rect) for rect in rects]), whole)
    assert_same_passes(assemble(prepared, render_tiles(prepared, threads=2)), whole)
    with ProcessPoolExecutor(1, mp_context=multiprocessing.get_context("spawn")) as pool:
        tile = pool.submit(render_tile, prepared, (0, 0, 24, 18)).result(timeout=120)
    assert_same_passes(tile.passes, {name: data for name, data in whole.items()})
    pinhole = render_image(replace(scene, camera=replace(scene.camera, aperture_radius=0.0, shutter_interval=None)),
                           settings)
    assert not np.array_equal(pinhole["Combined"], whole["Combined"])
    assert_same_passes({k: v for k, v in pinhole.items() if k != "Combined"},
                       {k: v for k, v in whole.items() if k != "Combined"})  # the passes stay the pinhole's

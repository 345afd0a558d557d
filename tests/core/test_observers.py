"""Moving observers (perspective, orthographic, panoramic) and several non-parallel moving frames in
one render, against a plain-numpy reference ray cast written here.

The reference shares no code with ``restframe_addon.core`` but the camera model's ray directions
(``core.camera.primary_rays``, checked against Cycles in ``tests/blender/test_blender_camera.py``):
textbook 4x4 boost matrices; each camera ray's events (camera frame) mapped, by the chain camera ->
world -> body, into the rest frame of each box, where the box is static and axis-aligned; the mapped
ray is a straight line in the observer's path length s, cut by slabs; the smallest s wins.  The
photon's 4-momentum mapped the same way gives every Doppler factor.
"""

import math

import numpy as np
import pytest
from references import boost_matrix
from shapes import box, look_at_camera, quad

from restframe_addon.core.camera import primary_rays
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Camera, Light, Material, Mesh, RenderSettings, Scene, Velocity

C = 10.0  # scene speed of light, so that the time passes are not the tracer's own units


def apply(matrix, tau, x):
    """Events (tau (n,), x (n, 3)) mapped by a 4x4 matrix."""
    events = np.column_stack([tau, x]) @ matrix.T
    return events[:, 0], events[:, 1:]


class Reference:
    """The plain-numpy ray cast of emissive boxes seen by a (moving) camera: per pixel centre the
    visible box, s, Doppler factor, world and body time of the hit, and the radiance."""

    def __init__(self, camera: Camera, res, tau_obs, boxes, world):
        n_x, n_y = res
        ys, xs = np.mgrid[0:n_y, 0:n_x]
        origins, d, s_lo, _, _ = primary_rays(camera, xs.ravel() + 0.5, ys.ravel() + 0.5, res)
        beta_c = np.asarray(camera.velocity.beta, dtype=np.float64)
        to_camera, from_camera = boost_matrix(beta_c), boost_matrix(-beta_c)
        position = np.asarray(camera.matrix)[:3, 3]
        # the observation event: the camera at world time tau_obs, in its own frame
        (t_cam,), (x_cam,) = apply(to_camera, [tau_obs], [position + beta_c * tau_obs])
        start = origins - position + x_cam  # orthographic rays start on the image plane
        n = len(d)
        photon = np.column_stack([np.ones(n), -d])  # the light's 4-momentum per unit camera-frame energy
        self.s = np.full(n, np.inf)
        self.index = np.full(n, -1)
        self.doppler = np.zeros(n)
        self.body_time = np.zeros(n)
        self.local = np.zeros((n, 3))  # rest-frame offset of the hit from its box's centre
        self.margin = np.zeros(n)  # how deep inside its face the hit is (0 at an edge), in rest-frame units
        step = np.column_stack([-np.ones(n), d])  # d(event)/ds along a backward ray
        for i, (centre, size, beta) in enumerate(boxes):
            to_body = boost_matrix(beta) @ from_camera  # camera -> world -> body
            a_t, a_x = apply(to_body, np.full(n, t_cam), start)
            b_t, b_x = apply(to_body, step[:, 0], step[:, 1:])
            # the body's origin event (tau = 0, centre), where its clock reads 0, in its rest frame
            (origin_t,), (rest_centre,) = apply(boost_matrix(beta), [0.0], [centre])
            lo, hi = rest_centre - 0.5 * np.asarray(size), rest_centre + 0.5 * np.asarray(size)
            with np.errstate(divide="ignore", invalid="ignore"):
                t1, t2 = (lo - a_x) / b_x, (hi - a_x) / b_x
            enter = np.nanmax(np.minimum(t1, t2), axis=1)
            leave = np.nanmin(np.maximum(t1, t2), axis=1)
            hit = (enter <= leave) & (enter > s_lo)
            nearer = hit & (enter < self.s)
            self.s[nearer], self.index[nearer] = enter[nearer], i
            k0 = (photon @ to_body.T)[:, 0]
            self.doppler[nearer] = 1.0 / k0[nearer]
            x_hit = a_x + enter[:, None] * b_x
            t_hit = a_t + enter * b_t
            self.body_time[nearer] = (t_hit - origin_t)[nearer]
            self.local[nearer] = (x_hit - rest_centre)[nearer]
            inside = np.minimum(x_hit - lo, hi - x_hit)
            self.margin[nearer] = np.sort(inside, axis=1)[nearer, 1]  # the smaller in-face distance
        seen = self.index >= 0
        event_t = t_cam - self.s[seen]
        event_x = start[seen] + self.s[seen, None] * d[seen]
        self.world_time = np.zeros(n)
        self.world_time[seen] = apply(from_camera, event_t, event_x)[0]
        self.world_doppler = 1.0 / (photon @ from_camera.T)[:, 0]
        self.world = np.outer(self.world_doppler**4, world)


def render(scene, res, **options):
    return render_image(scene, RenderSettings(resolution=res, threads=1, **options))


def emissive_boxes(boxes, emissions, curves=None):
    meshes = [Mesh(f"box{i}", *box(tuple(centre), tuple(size)), velocity=Velocity(tuple(beta)), pivot=tuple(centre),
                   material_indices=np.full(12, i), object_index=i + 1)
              for i, (centre, size, beta) in enumerate(boxes)]
    curves = curves or [None] * len(boxes)
    materials = [Material(f"glow{i}", base_color=(0, 0, 0), emission=e, specular_ior_level=0.0, emission_curve=c)
                 for i, (e, c) in enumerate(zip(emissions, curves))]
    return meshes, materials


def perspective(velocity):
    return look_at_camera((1.0, -2.0, 0.5), (1.0, 10.0, 0.5), fov_half_tan=1.2, velocity=velocity)


def orthographic(velocity):
    camera = look_at_camera((0.0, -8.0, 0.0), (0.0, 10.0, 0.0), velocity=velocity)
    camera.kind = "ORTHO"
    camera.frame = np.array([[12.0, 9.0, -1.0], [12.0, -9.0, -1.0], [-12.0, -9.0, -1.0], [-12.0, 9.0, -1.0]])
    camera.clip_start = 0.0
    return camera


def panoramic(velocity):
    camera = look_at_camera((0.0, 0.0, 0.0), (0.0, 10.0, 0.0), velocity=velocity)
    camera.kind = "PANO"
    camera.clip_start = 1e-3
    return camera


# three boxes, each with its own velocity: none parallel to another or to the camera's
BOXES = [((-3.0, 8.0, -1.0), (5.0, 3.0, 6.0), (0.0, 0.0, 0.7)),
         ((3.0, 6.0, 1.0), (4.0, 4.0, 4.0), (-0.5, -0.6, 0.2)),
         ((0.5, 14.0, 2.0), (12.0, 1.0, 8.0), (0.3, 0.0, -0.5))]
EMISSIONS = [(1.0, 0.5, 0.25), (0.2, 1.0, 0.4), (0.6, 0.3, 1.0)]
WORLD = (0.05, 0.1, 0.2)
# the clock of box 0 drives its emission (seconds of its own time -> multiplier)
CURVES = [(np.array([-10.0, 10.0]), np.array([-9.0, 11.0])), None, None]


@pytest.mark.parametrize("make_camera,camera_beta,res,t_obs", [
    (perspective, (0.0, 0.0, 0.0), (61, 41), 0.8),
    (perspective, (0.6, 0.0, 0.0), (61, 41), 0.8),
    (perspective, (-0.3, 0.5, 0.4), (61, 41), 0.3),
    (orthographic, (0.7, 0.0, 0.2), (64, 48), 0.8),
    (panoramic, (0.0, 0.8, 0.0), (96, 48), 0.8),
    (panoramic, (0.5, -0.2, 0.6), (96, 48), 0.8),
], ids=["static perspective", "perspective 0.6c across", "perspective 0.8c oblique", "orthographic 0.73c",
        "panoramic 0.8c forward", "panoramic 0.8c oblique"])
def test_moving_observer_sees_every_moving_frame_as_the_reference_ray_cast(make_camera, camera_beta, res, t_obs):
    """Every pass at every pixel: which box (IndexOB), observer path length (Depth), Doppler factor of the
    chain camera -> world -> box, world time (Emission Time) and box clock (Object Time) of the seen event,
    and the colour: emission (on the box's clock) x D^4, the world background x D_world^4."""
    camera = make_camera(Velocity(camera_beta))
    meshes, materials = emissive_boxes(BOXES, EMISSIONS, CURVES)
    scene = Scene(camera=camera, meshes=meshes, materials=materials, world_color=WORLD, tau_obs=C * t_obs,
                  light_speed=C)
    ref = Reference(camera, res, C * t_obs, BOXES, WORLD)
    passes = render(scene, res)
    index = passes["IndexOB"][..., 0].ravel().astype(int) - 1
    seen = ref.index >= 0
    assert seen.mean() > 0.04 and len(np.unique(ref.index[seen])) >= 2  # the test sees several frames
    # pixels on an edge may go either way in float32; anywhere else the visible box is the reference's
    clear = ~seen | (ref.margin > 0.02)
    assert np.mean(index[clear] != ref.index[clear]) < 0.005
    same = (index == ref.index) & seen & clear
    assert same.sum() > 0.9 * (seen & clear).sum()
    np.testing.assert_allclose(passes["Depth"][..., 0].ravel()[same], ref.s[same], rtol=2e-6)
    np.testing.assert_allclose(passes["Doppler"][..., 0].ravel()[same], ref.doppler[same], rtol=2e-6)
    np.testing.assert_allclose(passes["Emission Time"][..., 0].ravel()[same], ref.world_time[same] / C,
                               rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(passes["Object Time"][..., 0].ravel()[same], ref.body_time[same] / C,
                               rtol=1e-5, atol=1e-5)
    emission = np.array(EMISSIONS)[ref.index[same]]
    on_clock = ref.index[same] == 0
    emission[on_clock] *= np.interp(ref.body_time[same][on_clock] / C, *CURVES[0])[:, None]
    rgb = passes["Combined"][..., :3].reshape(-1, 3)
    np.testing.assert_allclose(rgb[same], emission * ref.doppler[same, None] ** 4, rtol=2e-5)
    # the background, at rest in the world: aberrated and scaled by D^4 of the camera's motion
    np.testing.assert_allclose(rgb[~seen & (index < 0)], ref.world[~seen & (index < 0)], rtol=2e-6)
    assert np.all(passes["Doppler"][..., 0].ravel()[~seen & (index < 0)] == 0.0)


def test_background_seen_by_a_camera_at_0_9c_is_brighter_ahead_by_d_to_the_4th():
    """No geometry at all: a camera moving at 0.9c along its view axis sees the uniform world radiance L
    times D^4 with D = 1/(gamma (1 - beta.d)), d the pixel's camera-frame direction (closed form): on the
    axis (the odd resolution puts a pixel centre there) D = sqrt(1.9 / 0.1)."""
    beta = 0.9
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=1.0, velocity=Velocity((0.0, beta, 0.0)))
    res = (21, 21)
    passes = render(Scene(camera=camera, world_color=WORLD, tau_obs=3.0), res)
    ys, xs = np.mgrid[0:21, 0:21]
    _, d, _, _, _ = primary_rays(camera, xs.ravel() + 0.5, ys.ravel() + 0.5, res)
    doppler = 1.0 / (1.0 / math.sqrt(1 - beta**2) * (1.0 - beta * d[:, 1]))
    rgb = passes["Combined"][..., :3].reshape(-1, 3)
    np.testing.assert_allclose(rgb, np.outer(doppler**4, WORLD), rtol=2e-6)
    assert rgb[10 * 21 + 10, 0] == pytest.approx(WORLD[0] * (1.9 / 0.1) ** 2, rel=1e-6)


def test_texture_keeps_its_orientation_on_a_moving_body():
    """A quad with a four-colour texture (one colour per quadrant), sliding across the view at 0.8c
    and lit by a sun moving with it: every pixel shows the texture colour of the rest-frame point the
    reference ray cast finds there (u to the right, v up, row 0 of the image at the bottom), times D^4.
    Aberration and Terrell rotation move and stretch the picture; they never mirror it."""
    beta = np.array([0.8, 0.0, 0.0])
    centre = np.array([0.0, 10.0, 0.0])
    v, t = quad(tuple(centre), (8.0, 6.0), normal_axis=1)  # corners (-x,-z) (x,-z) (x,z) (-x,z), facing -y
    corner_uv = np.array([[0.0, 0.0], [1.0, 0.0], [1.0, 1.0], [0.0, 1.0]])
    colours = np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0], [1.0, 1.0, 0.0]])  # quadrants (u, v) 00 10 01 11
    texture = np.empty((8, 8, 3))
    for q, colour in enumerate(colours):
        texture[4 * (q // 2):4 * (q // 2) + 4, 4 * (q % 2):4 * (q % 2) + 4] = colour  # row = v
    mesh = Mesh("poster", v, t, velocity=Velocity(tuple(beta)), pivot=tuple(centre), corner_uvs=corner_uv[t])
    sun = Light("sun", "SUN", (0, 0, 5.0), matrix=np.array([[1.0, 0, 0], [0, 0, -1.0], [0, 1.0, 0]]), power=math.pi,
                velocity=Velocity(tuple(beta)))  # shining along +y, straight onto the poster in its frame
    camera = look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.45)
    res = (45, 35)
    scene = Scene(camera=camera, meshes=[mesh], lights=[sun], world_color=(0, 0, 0), tau_obs=10.0,
                  materials=[Material("paper", base_color=(1, 1, 1), base_color_texture=texture, roughness=1.0,
                                      specular_ior_level=0.0)])
    passes = render(scene, res)
    ref = Reference(camera, res, 10.0, [(centre, (8.0, 1e-9, 6.0), beta)], (0, 0, 0))
    seen = ref.index >= 0
    assert 0.2 < seen.mean() < 0.9
    # the rest-frame hit point gives (u, v); pixels near a quadrant border or the poster's edge are skipped
    u, w = ref.local[:, 0] / 8.0 + 0.5, ref.local[:, 2] / 6.0 + 0.5
    clear = seen & (np.minimum(np.abs(u - 0.5), np.abs(w - 0.5)) > 0.15) & (np.minimum(u, w) > 0.15) \
        & (np.maximum(u, w) < 0.85)
    assert clear.sum() > 50
    expected = colours[(u[clear] > 0.5).astype(int) + 2 * (w[clear] > 0.5).astype(int)]
    rgb = passes["Combined"][..., :3].reshape(-1, 3)[clear]
    np.testing.assert_allclose(rgb, expected * ref.doppler[clear, None] ** 4, rtol=1e-4, atol=1e-6)
    for q in range(4):  # every quadrant is seen
        assert np.any(np.all(expected == colours[q], axis=1))


def fresnel(cos_i, n1, n2):
    """Unpolarised Fresnel reflectance (textbook s and p amplitudes)."""
    sin_t = n1 / n2 * math.sqrt(1.0 - cos_i**2)
    cos_t = math.sqrt(1.0 - sin_t**2)
    rs = (n1 * cos_i - n2 * cos_t) / (n1 * cos_i + n2 * cos_t)
    rp = (n2 * cos_i - n1 * cos_t) / (n2 * cos_i + n1 * cos_t)
    return 0.5 * (rs**2 + rp**2)


@pytest.mark.parametrize("beta", [0.0, 0.6, 0.9])
def test_glass_slab_moving_across_the_view_transmits_at_its_rest_frame_angle(beta):
    """A glass slab (n = 1.5) sliding sideways at beta in front of a static emitter, seen face-on.

    In the slab's frame the camera ray arrives aberrated, at cos(theta') = 1/gamma (closed form), so
    the Fresnel factors are those of that angle; the ray leaves the parallel slab in its entry
    direction, so the Doppler factors into and out of the slab cancel.  Transmitted radiance =
    L (1 - F)^2 / (1 - F^2) (every internal reflection; the bounce limit leaves out ~F^8).
    (Face-on at rest every angle is normal incidence: only the moving slab tells which way light
    crosses each face.)"""
    front, back = quad((0, 5.0, 0), (100, 100), normal_axis=1), quad((0, 5.5, 0), (100, 100), normal_axis=1)
    slab = [front, (back[0], back[1][:, ::-1])]  # a closed slab: front face toward the camera (-y), back face +y
    emitter = quad((0, 20.0, 0), (1e3, 1e3), normal_axis=1)
    v = Velocity((beta, 0.0, 0.0))
    mats = [Material("glass", base_color=(1, 1, 1), transmission=1.0, roughness=0.0, ior=1.5),
            Material("glow", base_color=(0, 0, 0), emission=(1.0, 1.0, 1.0), specular_ior_level=0.0)]
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01),
                  meshes=[Mesh("front", *slab[0], velocity=v, pivot=(0, 5.0, 0), material_indices=np.zeros(2, int)),
                          Mesh("back", *slab[1], velocity=v, pivot=(0, 5.0, 0), material_indices=np.zeros(2, int)),
                          Mesh("glow", *emitter, material_indices=np.ones(2, int))],
                  materials=mats, world_color=(0, 0, 0))
    value = render(scene, (9, 9), max_bounces=8)["Combined"][4, 4, 0]
    f = fresnel(math.sqrt(1.0 - beta**2), 1.0, 1.5)
    assert value == pytest.approx((1 - f) ** 2 / (1 - f**2), rel=1e-4)

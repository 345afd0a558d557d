"""Light transport across frames: closed forms for lights, mirrors and glass, and the relativity principle."""

import math

import numpy as np
import pytest
from shapes import look_at_camera, quad, rotation_x

from restframe_addon.core.render import render_image
from restframe_addon.core.sampling import Samples
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity

WHITE_LAMBERT = Material("white", base_color=(1.0, 1.0, 1.0), specular_ior_level=0.0, roughness=1.0)
BLACK = (0.0, 0.0, 0.0)


def gamma_of(beta):
    return 1.0 / math.sqrt((1.0 - beta) * (1.0 + beta))


def settings(res=(9, 9), **kw):
    return RenderSettings(resolution=res, threads=1, **kw)


def floor_scene(lights, floor_velocity=Velocity(), camera_velocity=Velocity(), tau=0.0):
    """A camera 1 above a white Lambert floor (z = 0), looking straight down at the origin."""
    camera = look_at_camera((0, 0, 1.0), (0, 0, 0), up=(0, 1, 0), fov_half_tan=0.01, velocity=camera_velocity)
    floor = quad((0, 0, 0), (1e4, 1e4))
    return Scene(camera=camera, meshes=[Mesh("floor", *floor, velocity=floor_velocity)], lights=lights,
                 materials=[WHITE_LAMBERT], world_color=BLACK, tau_obs=tau)


def centre(passes, name="Combined"):
    data = passes[name]
    return data[data.shape[0] // 2, data.shape[1] // 2]


def test_point_light_units_match_blender():
    """A point light of P watts at height 2: irradiance P / (4 pi r^2), radiance of white Lambert / pi."""
    passes = render_image(floor_scene([Light("lamp", "POINT", (0, 0, 2.0), power=1000.0)]), settings())
    assert centre(passes)[0] == pytest.approx(1000.0 / (4 * math.pi * 4.0) / math.pi, rel=1e-6)


def test_sun_and_spot_and_area_units():
    sun = Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_x(math.radians(60)), power=3.0)
    assert centre(render_image(floor_scene([sun]), settings()))[0] == pytest.approx(3.0 * 0.5 / math.pi, rel=1e-6)
    spot = Light("spot", "SPOT", (0, 0, 2.0), power=1000.0, spot_size=1.0, spot_blend=0.0)
    assert centre(render_image(floor_scene([spot]), settings()))[0] == pytest.approx(1000.0 / (16 * math.pi**2), rel=1e-6)
    away = Light("spot", "SPOT", (0, 0, 2.0), matrix=rotation_x(math.radians(60)), power=1000.0, spot_size=1.0)
    assert centre(render_image(floor_scene([away]), settings()))[0] == 0.0
    # a small square area light facing down: irradiance P / (pi r^2) (Lambertian emitter of radiance P / (pi A))
    area = Light("area", "AREA", (0, 0, 2.0), power=1000.0, area_size=(0.01, 0.01))
    value = centre(render_image(floor_scene([area]), settings()))[0]
    assert value == pytest.approx(1000.0 / (math.pi * 4.0) / math.pi, rel=1e-4)


@pytest.mark.parametrize("beta", [0.3, 0.9])
def test_light_moving_with_the_surface_shows_only_the_camera_doppler(beta):
    """Floor and a sun move together: in their frame nothing changes, so the camera sees the
    rest-frame radiance times D^4 (frequency-integrated radiance), D from the Doppler pass."""
    v = Velocity((beta, 0.0, 0.0))
    sun = Light("sun", "SUN", (0, 0, 5.0), power=2.0, velocity=v)
    for searchlight in (True, False):
        passes = render_image(floor_scene([sun], floor_velocity=v), settings(searchlight=searchlight))
        d = centre(passes, "Doppler")[0]
        assert d == pytest.approx(1.0 / gamma_of(beta), rel=1e-6)  # looking across the motion
        expected = 2.0 / math.pi * (d**4 if searchlight else 1.0)
        assert centre(passes)[0] == pytest.approx(expected, rel=1e-5)


@pytest.mark.parametrize("beta", [0.5, 0.9])
def test_relativity_principle_moving_lamp_or_moving_world(beta):
    """A lamp moving with -beta past a resting camera and floor looks exactly like camera and floor
    moving with +beta past a resting lamp (same events in the camera frame): D, depth and colour."""
    g = gamma_of(beta)
    tau_camera = 1.5
    lamp_a = Light("lamp", "POINT", (0.0, 0.7, 2.0), power=1000.0, velocity=Velocity((0.0, 0.0, -beta)),
                   pivot=(0.0, 0.7, 2.0))
    lamp_a.position = (0.0, 0.7, 2.0)
    # motion along z, all pivots with n.p = 0 except the floor (pivot at its own origin)
    a = floor_scene_side([lamp_a], Velocity(), Velocity(), tau_camera)
    lamp_b = Light("lamp", "POINT", (0.0, 0.7, 2.0), power=1000.0)
    v = Velocity((0.0, 0.0, beta))
    b = floor_scene_side([lamp_b], v, v, g * tau_camera)
    pa = render_image(a, settings((15, 15)))
    pb = render_image(b, settings((15, 15)))
    for name in ("Combined", "Doppler", "Depth"):
        assert np.allclose(pa[name], pb[name], rtol=1e-5, atol=1e-7), name
    assert pa["Combined"].max() > 0


def floor_scene_side(lights, floor_velocity, camera_velocity, tau):
    """A camera at (0, -4, 0) looking along +y at a white wall y = 0 (pivots off the motion axis z)."""
    camera = look_at_camera((0, -4.0, 0.0), (0, 0, 0), fov_half_tan=0.4, velocity=camera_velocity)
    wall = quad((0, 0, 0), (40, 40), normal_axis=1)
    return Scene(camera=camera, meshes=[Mesh("wall", *wall, velocity=floor_velocity, pivot=(0, 0, 0))], lights=lights,
                 materials=[WHITE_LAMBERT], world_color=BLACK, tau_obs=tau)


def mirror_scene(beta):
    """Camera at the origin looking +y at a mirror approaching head-on; an emitter behind the camera."""
    mirror = quad((0, 10.0, 0), (1e3, 1e3), normal_axis=1)
    emitter = quad((0, -5.0, 0), (1e3, 1e3), normal_axis=1)
    mats = [Material("mirror", base_color=(1, 1, 1), metallic=1.0, roughness=0.0),
            Material("glow", base_color=(0, 0, 0), emission=(1.0, 1.0, 1.0), specular_ior_level=0.0)]
    return Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01),
                 meshes=[Mesh("mirror", *mirror, velocity=Velocity((0, -beta, 0)), pivot=(0, 10, 0),
                              material_indices=np.zeros(2, int)),
                         Mesh("glow", *emitter, material_indices=np.ones(2, int))],
                 materials=mats, world_color=BLACK)


@pytest.mark.parametrize("beta", [0.0, 0.1, 0.5])
def test_approaching_mirror_doubles_the_doppler_shift(beta):
    """Light reflected by a mirror approaching head-on returns with (1 + b)/(1 - b): the Doppler
    factors of the two frame changes multiply; the radiance scales with its 4th power."""
    passes = render_image(mirror_scene(beta), settings())
    double = (1 + beta) / (1 - beta)
    assert centre(passes)[0] == pytest.approx(double**4, rel=1e-6)
    assert centre(passes, "Doppler")[0] == pytest.approx(math.sqrt(double), rel=1e-6)  # the mirror itself


def test_glass_slab_transmits_fresnel_weighted_light():
    """Normal incidence through a glass slab (n = 1.5): (1 - F)^2 with F = 0.04, plus the small
    multiply reflected terms the bounce limit allows."""
    front = quad((0, 5.0, 0), (100, 100), normal_axis=1)
    back = quad((0, 5.5, 0), (100, 100), normal_axis=1)
    emitter = quad((0, 20.0, 0), (1e3, 1e3), normal_axis=1)
    mats = [Material("glass", base_color=(1, 1, 1), transmission=1.0, roughness=0.0, ior=1.5),
            Material("glow", base_color=(0, 0, 0), emission=(1.0, 1.0, 1.0), specular_ior_level=0.0)]
    scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0), fov_half_tan=0.01),
                  meshes=[Mesh("front", *front, material_indices=np.zeros(2, int)),
                          Mesh("back", *back, material_indices=np.zeros(2, int)),
                          Mesh("glow", *emitter, material_indices=np.ones(2, int))],
                  materials=mats, world_color=BLACK)
    value = centre(render_image(scene, settings(max_bounces=8)))[0]
    f = 0.04
    series = (1 - f) ** 2 / (1 - f**2)  # all internal reflections summed
    assert value == pytest.approx(series, rel=1e-3)
    assert centre(render_image(scene, settings(max_bounces=0)))[0] == 0.0  # refraction needs a bounce


def test_sun_seen_from_a_moving_surface_is_aberrated_and_scaled_by_d_squared():
    """A floor sliding along x at beta under a sun straight above (at rest in S).

    The sunlight is perpendicular to the motion in the *emitter's* frame, so the floor sees it
    blue-shifted, D = gamma, arriving from ahead: backward direction (beta, 0, 1/gamma), cos = 1/gamma.
    Irradiance E' D^2 cos = 2 gamma^2 / gamma.
    """
    beta = 0.6
    g = gamma_of(beta)
    sun = Light("sun", "SUN", (0, 0, 5.0), power=2.0)
    v = Velocity((beta, 0, 0))
    passes = render_image(floor_scene([sun], floor_velocity=v, camera_velocity=v), settings())
    assert centre(passes)[0] == pytest.approx(2.0 * g**2 / g / math.pi, rel=1e-6)
    assert centre(passes, "Doppler")[0] == pytest.approx(1.0, rel=1e-9)  # the camera moves with the floor
    still = render_image(floor_scene([sun], floor_velocity=v, camera_velocity=v), settings(searchlight=False))
    assert centre(still)[0] == pytest.approx(2.0 / g / math.pi, rel=1e-6)  # only the aberrated cosine


def test_a_sharp_suns_light_mapped_once_per_frame_is_bit_for_bit_each_hits_own():
    """The sharp sun's direction is one for every hit: it is mapped into the surface's frame once
    and broadcast.  Every hit's direction, D and irradiance factor must be exactly those of
    mapping that hit's own copy of the direction (contiguous rows), on a floor sliding obliquely."""
    from restframe_addon.core.prepared import prepare

    tilt = np.linalg.qr(np.array([[1.0, 0.3, -0.2], [-0.3, 1.0, 0.1], [0.2, -0.1, 1.0]]))[0]  # a rotation
    sun = Light("sun", "SUN", (0, 0, 5.0), matrix=tilt * np.sign(np.linalg.det(tilt)), power=2.0)
    prepared = prepare(floor_scene([sun], floor_velocity=Velocity((0.6, -0.3, 0.2))), settings())
    shader = prepared.shader
    (k,) = shader.frames.geometry  # the floor's frame
    pl = shader.lights[0]
    to_surface = shader.frames.map(pl.frame, k)
    assert not to_surface.is_identity
    n = 7
    rng = np.random.default_rng(3)
    e_k, strength, doppler, s_max, _ = shader._incident(pl, k, rng.uniform(-1, 1, n), rng.uniform(-1, 1, (n, 3)),
                                                        None, None)
    own_e, own_w = to_surface.rays(np.tile(pl.axes[:, 2], (n, 1)))
    assert e_k.shape == (n, 3) and np.array_equal(e_k, own_e)
    assert np.array_equal(doppler, own_w) and np.array_equal(strength, shader.searchlight_power(own_w, 2))
    assert s_max == np.inf


@pytest.mark.parametrize("sun", [False, True])
def test_culled_shadow_rays_block_exactly_as_unculled_ones(monkeypatch, sun):
    """Shadow-ray bundles skip frames whose body cannot reach them (finite rays: a swept
    capsule; sunlight: a half-cylinder along the common direction).  Against many small
    boxes moving at random velocities, the blocked rays must be exactly those found when
    every frame is queried -- and the culling must have skipped some frames."""
    from shapes import box

    from restframe_addon.core import tracer
    from restframe_addon.core.frames import build_frames

    rng = np.random.default_rng(7)
    meshes = []
    for i in range(60):
        centre = rng.uniform(-6.0, 6.0, 3)
        beta = rng.normal(size=3)
        beta *= rng.uniform(0.0, 0.95) / np.linalg.norm(beta)
        meshes.append(Mesh(f"box{i}", *box(tuple(centre), (1.2, 1.2, 1.2)), velocity=Velocity(tuple(beta)),
                           pivot=tuple(centre)))
    frames = build_frames(Scene(camera=look_at_camera((0, -20, 0), (0, 0, 0)), meshes=meshes))
    n = 400
    # bundles of 40 rays from small patches (as a tile's hits), something to cull
    x0 = np.repeat(rng.uniform(-4.0, 4.0, (n // 40, 3)), 40, axis=0) + rng.uniform(-0.3, 0.3, (n, 3))
    tau0 = rng.uniform(-1.0, 1.0, n)
    if sun:
        d = np.broadcast_to(np.array([0.3, -0.2, 0.9]) / np.linalg.norm([0.3, -0.2, 0.9]), (n, 3))
        s_hi = np.full(n, np.inf)
    else:
        d = rng.normal(size=(n, 3))
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        s_hi = rng.uniform(0.5, 4.0, n)
    src = frames.world
    queried = []
    original = tracer._may_meet
    monkeypatch.setattr(tracer, "_may_meet", lambda *a: queried.extend(original(*a)) or original(*a))
    bundles = [slice(i, i + 40) for i in range(0, n, 40)]
    culled = np.concatenate([tracer.occluded(frames, src, tau0[b], x0[b], d[b], 1e-6, s_hi[b]) for b in bundles])
    monkeypatch.setattr(tracer, "_may_meet", lambda frames, src, ks, reach, cache: np.ones(len(ks), dtype=bool))
    full = np.concatenate([tracer.occluded(frames, src, tau0[b], x0[b], d[b], 1e-6, s_hi[b]) for b in bundles])
    np.testing.assert_array_equal(culled, full)
    assert 0 < np.count_nonzero(full) < n
    assert queried.count(False) > 0
    # bundles from several source frames through one thread's TraceCache (every source's body boxes
    # worked out at once, a sun direction's maps kept: the second round reads them) and without one
    monkeypatch.setattr(tracer, "_may_meet", original)
    cache = tracer.TraceCache()
    for i, b in enumerate(bundles * 2):
        k = frames.geometry[i % 7]
        np.testing.assert_array_equal(tracer.occluded(frames, k, tau0[b], x0[b], d[b], 1e-6, s_hi[b], cache),
                                      tracer.occluded(frames, k, tau0[b], x0[b], d[b], 1e-6, s_hi[b]))


def test_segment_box_test_handles_axis_parallel_segments_on_faces():
    from restframe_addon.core.tracer import _segments_meet_boxes

    lo, hi = np.zeros((4, 3)), np.ones((4, 3))
    origin = np.array([[0.0, 0.5, -1.0],   # on the x = 0 face, moving along z: meets
                       [-1e-9, 0.5, -1.0],  # just outside that face, moving along z: misses
                       [0.5, 0.5, -1.0],    # straight through
                       [0.5, 0.5, -1.0]])   # too short to reach
    direction = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, 1.0], [0.0, 0.0, 3.0], [0.0, 0.0, 0.9]])
    lo, hi, origin, direction = lo.T, hi.T, origin.T, direction.T  # a row per axis
    np.testing.assert_array_equal(_segments_meet_boxes(origin, direction, 1.0, lo, hi, direction == 0.0),
                                  [True, False, True, False])
    # from the origin (None): the boxes moved by -origin
    np.testing.assert_array_equal(_segments_meet_boxes(None, direction, 1.0, lo - origin, hi - origin,
                                                       direction == 0.0), [True, False, True, False])
    # no component 0 (parallel None): the plain slab test
    tilted = direction + 0.25
    np.testing.assert_array_equal(_segments_meet_boxes(origin, tilted, 1.0, lo, hi, None),
                                  _segments_meet_boxes(origin, tilted, 1.0, lo, hi, tilted == 0.0))


def test_cone_and_disc_sample_angles_in_float32_change_images_by_under_a_millionth(monkeypatch):
    """The angles about a cone's axis (a sun with an angle) and a disc's centre (a soft point lamp,
    a disc area lamp) are taken in float32 (``shading.UNIT_CIRCLE_DTYPE``): against the float64
    trigonometry they replaced (the same code with float64), every pixel agrees to 1e-6 relative,
    on a rough glossy floor seen from a camera at 0.5c."""
    from restframe_addon.core import shading

    lights = [Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_x(math.radians(30)), power=3.0, sun_angle=0.3),
              Light("soft", "POINT", (1.0, 0.5, 1.5), power=300.0, radius=0.4),
              Light("disc", "AREA", (-1.0, 0.0, 1.0), power=200.0, area_size=(0.6, 0.6), area_shape="DISK")]
    camera = look_at_camera((0.0, -3.0, 2.0), (0, 0, 0), fov_half_tan=0.6, velocity=Velocity((0.0, 0.5, 0.0)))
    floor = quad((0, 0, 0), (1e3, 1e3))
    plastic = Material("plastic", base_color=(0.6, 0.5, 0.4), roughness=0.4)
    scene = Scene(camera=camera, meshes=[Mesh("floor", *floor)], lights=lights, materials=[plastic],
                  world_color=BLACK)
    fast = render_image(scene, settings((24, 24), samples=8))["Combined"]
    monkeypatch.setattr(shading, "UNIT_CIRCLE_DTYPE", np.float64)
    reference = render_image(scene, settings((24, 24), samples=8))["Combined"]
    assert np.all(reference[..., 0] > 0.0)
    assert not np.array_equal(fast, reference)  # the trade is exercised
    np.testing.assert_allclose(fast, reference, rtol=1e-6, atol=0.0)


def test_ggx_from_cosines_changes_images_by_at_most_one_float32_step(monkeypatch):
    """Direct Light's GGX highlights from three dot products (``bsdf.ggx_single``, no half vector;
    1e-10 relative of the half-vector form, test_bsdf): against the half-vector form they replaced
    (``references.half_vector_ggx``), the float32 Combined pass agrees bit for bit at 99% of its
    values and to one rounding step elsewhere, on rough glossy dielectric and metal floors under
    a sun with an angle and a point lamp, seen from a camera at 0.5c."""
    from references import half_vector_ggx

    from restframe_addon.core import shading

    def half_vector_reflection(n, view, light, alpha, f0, f90, cos_l=None, cos_v=None):
        single, cos_vh = half_vector_ggx(n, view, light, alpha)
        schlick = (1.0 - cos_vh) ** 5
        return (f0 * (1.0 - schlick)[:, None] + (f90 * schlick)[:, None]) * single[:, None]

    lights = [Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_x(math.radians(30)), power=3.0, sun_angle=0.3),
              Light("lamp", "POINT", (1.0, 0.5, 1.5), power=300.0)]
    camera = look_at_camera((0.0, -3.0, 2.0), (0, 0, 0), fov_half_tan=0.6, velocity=Velocity((0.0, 0.5, 0.0)))
    materials = [Material("plastic", base_color=(0.6, 0.5, 0.4), roughness=0.2),
                 Material("metal", base_color=(0.9, 0.6, 0.3), metallic=1.0, roughness=0.5)]
    floors = [Mesh("left", *quad((-500.0, 0, 0), (1e3, 1e3))),
              Mesh("right", *quad((500.0, 0, 0), (1e3, 1e3)), material_indices=np.ones(2, dtype=np.int64))]
    scene = Scene(camera=camera, meshes=floors, lights=lights, materials=materials, world_color=BLACK)
    fast = render_image(scene, settings((24, 24), samples=8))["Combined"]
    monkeypatch.setattr(shading, "ggx_reflection", half_vector_reflection)
    reference = render_image(scene, settings((24, 24), samples=8))["Combined"]
    assert np.all(reference[..., 0] > 0.0)
    np.testing.assert_allclose(fast, reference, rtol=np.finfo(np.float32).eps, atol=0.0)
    assert np.mean(fast == reference) > 0.99


def test_float32_base_colour_textures_blend_in_float32_to_a_millionth(monkeypatch):
    """A float32 base-colour image (as Blender's) is blended in float32 (world.Texels colour=True):
    against the float64 blend, every value of the Combined pass agrees to 1e-6 of the image's
    brightest value, on a rough glossy floor with a dark and bright texture under a sun with an
    angle, seen from a camera at 0.5c."""
    from restframe_addon.core import shading
    from restframe_addon.core.world import Texels

    rng = np.random.default_rng(2)
    texture = (rng.random((32, 32, 3)) ** 4).astype(np.float32)
    vertices, triangles = quad((0, 0, 0), (1e3, 1e3))
    corner_uv = np.array([[0.0, 0.0], [300.0, 0.0], [300.0, 300.0], [0.0, 300.0]])  # repeated (a 10 cm texel)
    floor = Mesh("floor", vertices, triangles, corner_uvs=corner_uv[triangles])
    lights = [Light("sun", "SUN", (0, 0, 5.0), matrix=rotation_x(math.radians(30)), power=3.0, sun_angle=0.05)]
    camera = look_at_camera((0.0, -3.0, 2.0), (0, 0, 0), fov_half_tan=0.6, velocity=Velocity((0.0, 0.5, 0.0)))
    paper = Material("paper", base_color=(1, 1, 1), base_color_texture=texture, roughness=0.5)
    scene = Scene(camera=camera, meshes=[floor], lights=lights, materials=[paper], world_color=BLACK)
    fast = render_image(scene, settings((24, 24), samples=4))["Combined"]
    monkeypatch.setattr(shading, "_texels", lambda image, colour=False: None if image is None else Texels(image))
    reference = render_image(scene, settings((24, 24), samples=4))["Combined"]
    assert np.all(reference[..., 0] > 0.0)
    assert not np.array_equal(fast, reference)  # the trade is exercised
    np.testing.assert_allclose(fast, reference, rtol=0.0, atol=1e-6 * reference[..., :3].max())


def test_one_material_shades_bit_for_bit_as_gathered_per_hit():
    """Direct Light's BSDF for a batch of hits on one material (its constants as 1-element arrays,
    a dielectric's F0 as one grey column) is bit for bit the value with the constants gathered per
    hit (hits on several materials), for a glossy dielectric, a rough metal and a Lambert surface."""
    from restframe_addon.core.prepared import prepare

    materials = [Material("plastic", base_color=(0.6, 0.5, 0.4), roughness=0.4),
                 Material("metal", base_color=(0.9, 0.6, 0.3), metallic=1.0, roughness=0.5),
                 WHITE_LAMBERT]
    camera = look_at_camera((0.0, -3.0, 2.0), (0, 0, 0))
    scene = Scene(camera=camera, meshes=[Mesh("floor", *quad((0, 0, 0), (10.0, 10.0)))], materials=materials,
                  lights=[Light("lamp", "POINT", (0, 0, 2.0), power=100.0)], world_color=BLACK)
    shader = prepare(scene, settings()).shader
    rng = np.random.default_rng(7)
    n = 300
    ns = np.tile([0.0, 0.0, 1.0], (n, 1))
    view, light = (rows_normalized(rng.normal(size=(n, 3)) + [0.0, 0.0, 2.0]) for _ in range(2))
    base = rng.random((n, 3))
    mixed = np.arange(n) % 3
    together = shader.brdf(ns, view, light, base, mixed)
    for m in range(3):
        alone = np.flatnonzero(mixed == m)
        value = shader.brdf(ns[alone], view[alone], light[alone], base[alone], np.full(len(alone), m))
        assert np.array_equal(value, together[alone]), materials[m].name
        diffuse = base[alone] * (1.0 - materials[m].metallic) / np.pi
        assert np.any(value > diffuse * (1.0 + 1e-9)) == (m < 2)  # the glossy ones have their GGX lobe


def test_hit_materials_are_the_clamped_triangle_materials_broadcast_for_one_material_bodies():
    """Shader.hit_materials gives every hit its triangle's material number, clamped to the table (as
    a gather of tri_material would): one number broadcast (no gather) for a body whose triangles
    all have one, even an out-of-range one; gathered for a body of two materials."""
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.shading import _only_material

    meshes = [Mesh("two", *quad((0, 0, 0), (10.0, 10.0)), material_indices=np.array([0, 1])),
              Mesh("one", *quad((0, 0, 1.0), (2.0, 2.0)), material_indices=np.array([7, 7]),
                   velocity=Velocity((0.3, 0.0, 0.0)))]
    scene = Scene(camera=look_at_camera((0.0, -3.0, 2.0), (0, 0, 0)), meshes=meshes,
                  materials=[Material("a"), Material("b", base_color=(0.2, 0.4, 0.6))],
                  lights=[Light("lamp", "POINT", (0, 0, 2.0), power=100.0)], world_color=BLACK)
    shader = prepare(scene, settings()).shader
    broadcast = []
    for k in shader.frames.geometry:
        geometry = shader.frames.frames[k].geometry
        prim = np.arange(len(geometry.tri_material)).repeat(3)
        got = shader.hit_materials(k, prim)
        np.testing.assert_array_equal(got, np.clip(geometry.tri_material[prim], 0, 1))
        broadcast.append(got.strides == (0,))
        assert _only_material(got) == (1 if broadcast[-1] else None)
    assert sorted(broadcast) == [False, True]


def rows_normalized(a):
    return a / np.linalg.norm(a, axis=1, keepdims=True)


def test_rows_take_gathers_rows_as_fancy_indexing_does_in_either_layout():
    """rows.take gives ``a[index]`` for indices, masks and slices, of row-major and of column-major
    arrays (these column by column, into contiguous columns), of (n, 3) and (n, 16) rows."""
    from restframe_addon.core import rows

    rng = np.random.default_rng(5)
    for columns in (3, 16):
        rows_major = rng.random((500, columns))
        for a in (rows_major, np.asfortranarray(rows_major)):
            for index in (rng.choice(500, 200, replace=False), rng.random(500) < 0.3, np.arange(0),
                          np.zeros(500, dtype=bool), slice(10, 90)):
                taken = rows.take(a, index)
                np.testing.assert_array_equal(taken, rows_major[index])
                assert taken.shape == rows_major[index].shape
            if a.flags.f_contiguous and columns <= 4:
                assert rows.take(a, np.arange(7)).flags.f_contiguous  # the caller's layout kept


def test_rows_of_a_broadcast_row_are_taken_as_one_row_and_dotted_as_its_rows_are():
    """rows.take of one broadcast row (or number) gives it again as the selected rows, no gather;
    rows.dot of a broadcast row and rows (either side) gives what it gives of its rows written out:
    the same bits where BLAS sums the matrix-vector product ``(a0 b0 + a1 b1) + a2 b2`` (OpenBLAS on
    the x86 machines measured), within the rounding of a three-term sum where another BLAS kernel
    orders it otherwise (so the test holds whichever kernel numpy's BLAS picks for the CPU)."""
    from restframe_addon.core import rows

    rng = np.random.default_rng(8)
    row, b = rng.normal(size=(1, 3)), rng.normal(size=(70000, 3))
    one = rows.broadcast(row, len(b))
    assert rows.is_broadcast(one) and not one.flags.writeable and not rows.is_broadcast(b)
    for index in (rng.choice(len(b), 900, replace=False), rng.random(len(b)) < 0.3, slice(5, 60)):
        taken = rows.take(one, index)
        assert rows.is_broadcast(taken)
        np.testing.assert_array_equal(taken, np.repeat(row, len(b), axis=0)[index])
    number = rows.take(rows.broadcast(np.array([7]), 10), np.arange(4))
    assert number.shape == (4,) and rows.is_broadcast(number) and (number == 7).all()
    written = np.repeat(row, len(b), axis=0)
    for dotted, expected in ((rows.dot(one, b), rows.dot(written, b)), (rows.dot(b, one), rows.dot(b, written))):
        sizes = np.abs(row[0, 0] * b[:, 0]) + np.abs(row[0, 1] * b[:, 1]) + np.abs(row[0, 2] * b[:, 2])
        assert np.all(np.abs(dotted - expected) <= 2 * np.finfo(float).eps * sizes)
        exact = (row[0, 0] * b[:, 0] + row[0, 1] * b[:, 1]) + row[0, 2] * b[:, 2]
        np.testing.assert_array_equal(dotted, exact)  # the column form's own sum, in its order


def test_rows_put_assigns_rows_as_fancy_indexing_does():
    """rows.put (whole rows copied by np.put) gives what ``a[index] = new`` gives, and rows.assign
    (column by column between layouts) what ``a[...] = new`` gives: (n, 3) and (n, 16) rows, a
    float32, broadcast or column-major ``new``, a non-contiguous target."""
    from restframe_addon.core import rows

    rng = np.random.default_rng(3)
    for columns in (3, 16):
        index = rng.choice(500, 200, replace=False)
        for new in (rng.random((200, columns)), rng.random((200, columns)).astype(np.float32),
                    np.broadcast_to(rng.random(columns), (200, columns)), rng.random((columns, 200)).T):
            for target in (rng.random((500, columns)), rng.random((columns, 500)).T):
                expected = target.copy()
                expected[index] = new
                rows.put(target, index, new)
                np.testing.assert_array_equal(target, expected)
                rows.assign(target[:200], new)
                np.testing.assert_array_equal(target[:200], new)


def test_rows_scale_in_place_gives_the_rows_times_their_scalars():
    """rows.scale(a, s, out=a) (GGX's Fresnel term times the lobe, no new array) is ``a * s[:, None]``
    bit for bit, for one, three and sixteen columns, and returns a itself."""
    from restframe_addon.core import bsdf, rows

    rng = np.random.default_rng(5)
    s = rng.random(300)
    for columns in (1, 3, 16):
        a = rng.random((300, columns))
        expected = a * s[:, None]
        assert rows.scale(a, s, out=a) is a
        np.testing.assert_array_equal(a, expected)
    cos_i, f0, f90 = rng.random(300) * 1.2 - 0.1, rng.random((300, 3)), rng.random(300)
    s5 = (1.0 - np.clip(cos_i, 0.0, 1.0)) ** 2
    s5 = s5 * s5 * (1.0 - np.clip(cos_i, 0.0, 1.0))
    np.testing.assert_array_equal(bsdf.fresnel_schlick(cos_i, f0, f90),
                                  f0 * (1.0 - s5)[:, None] + (f90 * s5)[:, None])


@pytest.mark.parametrize("mode", ["OFF", "SPECTRAL"])
def test_every_frames_hits_shaded_together_give_each_frames_own_bits(mode):
    """The shader and the passes work on every frame's hits at once (what depends on the frame
    worked out frame by frame and joined, the rest once, the values scattered back): each ray's
    values must be exactly those of shading the rays of its frame alone.  A floor at rest with
    the camera, boxes at three velocities (one spinning), a glossy, a mirror and a diffuse material, a sharp
    sun and a soft point lamp; the Doppler, Normal, IndexOB and Object Time passes likewise."""
    from shapes import box

    from restframe_addon.core.passes import DEFAULT_PASSES, pixel_passes
    from restframe_addon.core.prepared import prepare
    from restframe_addon.core.scene import RAY_CAMERA
    from restframe_addon.core.tracer import TraceCache, frames_hit

    materials = [Material("grey", base_color=(0.6, 0.5, 0.4)),
                 Material("glossy", base_color=(0.2, 0.7, 0.3), roughness=0.4),
                 Material("mirror", base_color=(0.9, 0.9, 0.9), roughness=0.0, metallic=1.0)]
    meshes = [Mesh("floor", *quad((0, 0, 0), (40.0, 40.0)))]
    for i, (beta, spin) in enumerate((((0.3, 0.0, 0.0), None), ((-0.5, 0.1, 0.0), (0.0, 0.0, 0.4)),
                                      ((0.2, 0.4, 0.0), None))):
        centre = (-3.0 + 3.0 * i, 2.0, 1.0)
        v, t = box(centre, (1.5, 1.5, 2.0))
        meshes.append(Mesh(f"box{i}", v, t, velocity=Velocity(beta), pivot=centre, angular_velocity=spin,
                           material_indices=np.full(len(t), i), object_index=i + 1))
    lights = [Light("sun", "SUN", (0, 0, 10.0), matrix=rotation_x(math.radians(40)), power=2.0),
              Light("lamp", "POINT", (1.0, -2.0, 4.0), power=800.0, radius=0.3)]
    scene = Scene(camera=look_at_camera((0.0, -9.0, 5.0), (0.0, 2.0, 0.5), fov_half_tan=0.6), meshes=meshes,
                  lights=lights, materials=materials, world_color=(0.05, 0.1, 0.2))
    res = (32, 24)
    prepared = prepare(scene, settings(res, doppler_mode=mode, spectral_samples=8, passes=tuple(DEFAULT_PASSES)))
    shader, camera, rect = prepared.shader, prepared.frames.camera, (0, 0, *res)
    rays = prepared.centre_rays(rect)
    pixel = prepared.pixel_ids(rect)
    sample = np.zeros_like(pixel)
    lam = prepared.colour.camera_wavelengths(pixel, sample)
    hits = shader.trace(camera, *rays, RAY_CAMERA, pixel, sample, 0, TraceCache())
    values, _ = shader.radiance(camera, *rays, 0, Samples(pixel, sample), lam, hits, TraceCache())
    passes = pixel_passes(prepared.frames, scene.light_speed, DEFAULT_PASSES, rays, hits, None, TraceCache())
    frames = frames_hit(hits)
    assert len(frames) == 4  # the floor (at rest with the camera) and the three boxes (one spinning)
    assert any(prepared.frames.frames[k].spin is not None for k in frames)
    for k in frames:
        mine = np.flatnonzero(hits.frame == k)
        part = tuple(np.take(a, mine, axis=0) if np.ndim(a) else a for a in rays)
        alone, _ = shader.radiance(camera, *part, 0, Samples(pixel[mine], sample[mine]),
                                   None if lam is None else lam[mine], hits.take(mine), TraceCache())
        assert np.array_equal(values[mine], alone)
        alone_passes = pixel_passes(prepared.frames, scene.light_speed, DEFAULT_PASSES, part, hits.take(mine))
        for name in ("Doppler", "Normal", "IndexOB", "Object Time"):
            assert np.array_equal(passes[name][mine], alone_passes[name]), name

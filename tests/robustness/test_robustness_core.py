"""Bad and odd input to the core (issue 9): every case ends in a correct image or a clear error."""

import numpy as np
import pytest

from restframe_addon.core.prepared import prepare
from restframe_addon.core.render import RenderError, render_image, render_tiles
from restframe_addon.core.scene import Light, Mesh, RenderSettings, Scene, Velocity
from shapes import box, look_at_camera, quad, uv_sphere


def settings(res=(15, 11), **kw):
    kw.setdefault("threads", 1)
    return RenderSettings(resolution=res, **kw)


def lamp(position=(2.0, -3.0, 4.0), power=500.0):
    return Light("Lamp", "POINT", position, power=power)


def ball_scene(velocity=Velocity(), **kw):
    v, t = uv_sphere((0, 0, 0), 1.0, 16, 8)
    return Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), meshes=[Mesh("Ball", v, t, velocity=velocity)],
                 lights=[lamp()], **kw)


def assert_sane(passes):
    for name, data in passes.items():
        assert np.all(np.isfinite(data)), name
    assert passes["Combined"].min() >= 0.0
    assert passes["Doppler"].min() >= 0.0


@pytest.mark.parametrize("velocity, message", [
    (Velocity((1.0, 0.0, 0.0)), "Ball"),
    (Velocity((0.8, 0.7, 0.0)), "Ball"),
    (Velocity((float("nan"), 0.0, 0.0)), "Ball"),
    (Velocity((float("inf"), 0.0, 0.0)), "Ball"),
    (Velocity((0.5, 0.0, 0.0), lorentz_factor=0.5), "Ball"),
    (Velocity((0.0, 0.0, 0.0), lorentz_factor=2.0), "Ball"),
])
def test_unphysical_velocities_are_refused_naming_the_object(velocity, message):
    with pytest.raises(RenderError, match=message):
        render_image(ball_scene(velocity), settings())


def test_no_camera():
    scene = ball_scene()
    scene.camera = None
    with pytest.raises(RenderError, match="no camera"):
        render_image(scene, settings())


@pytest.mark.parametrize("res", [(0, 0), (0, 10), (10, 0), (-4, 4)])
def test_zero_resolution(res):
    with pytest.raises(RenderError, match="no pixels"):
        render_image(ball_scene(), settings(res))


def _rss_mb():
    for line in open("/proc/self/status"):
        if line.startswith("VmRSS:"):
            return int(line.split()[1]) / 1024.0


def test_huge_resolution_renders_a_border_region_in_bounded_memory():
    """A 100000x100000 image (10^10 pixels): the tiles of a small region stream without the whole image."""
    res = (100_001, 100_001)
    scene = ball_scene()
    scene.camera = look_at_camera((0, -6, 0), (0, 0, 0), fov_half_tan=0.2)
    centre = res[0] // 2
    region = (centre - 16, centre - 16, centre + 16, centre + 16)
    before = _rss_mb()
    tiles = list(render_tiles(prepare(scene, settings(res, region=region, tile_size=16))))
    assert _rss_mb() - before < 200  # the full image's passes alone would be 560 GB
    assert len(tiles) == 4
    for tile in tiles:
        assert tile.passes["Doppler"].shape == (16, 16, 1)
        assert np.all(tile.passes["Doppler"] == 1.0)  # the image centre is on the ball
        assert np.all(np.isfinite(tile.passes["Combined"]))


def test_empty_scene_renders_the_background():
    scene = Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), world_color=(0.1, 0.2, 0.3))
    passes = render_image(scene, settings())
    assert_sane(passes)
    assert np.all(passes["Doppler"] == 0.0)
    np.testing.assert_allclose(passes["Combined"][..., :3], np.broadcast_to([0.1, 0.2, 0.3], (11, 15, 3)), atol=1e-6)


def test_odd_geometry_renders_or_is_skipped_with_a_warning():
    v, t = quad((0, 0, 0), (2, 2), normal_axis=1)
    nan_v = v.copy()
    nan_v[0] = np.nan
    degenerate_v = np.array([[0, 0, 0], [1, 0, 0], [2, 0, 0], [0, 0, 0]], float)  # collinear and zero-area
    fin_v = np.array([[0, 0, 0], [1, 0, 0], [0, 0, 1], [0, 1, 0], [0, -1, 0]], float)  # 3 triangles on one edge
    meshes = [
        Mesh("NoFaces", v, np.zeros((0, 3), int)),
        Mesh("NoVertices", np.zeros((0, 3)), np.zeros((0, 3), int)),
        Mesh("Degenerate", degenerate_v, np.array([[0, 1, 2], [0, 0, 3], [1, 1, 1]])),
        Mesh("NonManifold", fin_v + (0, 0, -2), np.array([[0, 1, 2], [0, 1, 3], [0, 1, 4]])),
        Mesh("NaN", nan_v + (0, 1, 0), t),
        Mesh("BadIndex", v, np.array([[0, 1, 7]])),
        Mesh("Wall", v + (0, 3, 0), t, velocity=Velocity((0.5, 0, 0))),
    ]
    scene = Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), meshes=meshes, lights=[lamp()])
    renderer = prepare(scene, settings())
    assert any(w.startswith("NaN: skipped 2 triangles") for w in renderer.warnings)
    assert any(w.startswith("BadIndex: skipped 1 triangles") for w in renderer.warnings)
    passes = render_image(scene, settings())
    assert_sane(passes)
    hit = passes["Doppler"][..., 0] > 0
    assert hit.sum() > 4  # the wall and the valid odd meshes are seen
    assert np.any(passes["Doppler"][..., 0][hit] != 1.0)  # the moving wall among them


def test_camera_inside_an_object_sees_its_inside():
    v, t = box((0, 0, 0), (4, 4, 4))
    for velocity in (Velocity(), Velocity((0.6, 0.0, 0.0))):
        scene = Scene(camera=look_at_camera((0, 0, 0), (0, 1, 0)), meshes=[Mesh("Room", v, t, velocity=velocity)],
                      lights=[lamp((0.5, 0.5, 0.5))])
        passes = render_image(scene, settings())
        assert_sane(passes)
        assert np.all(passes["Doppler"] > 0)  # every ray hits a wall from inside
        assert np.all(passes["Emission Time"] <= 0.0)


def test_object_passing_through_the_camera():
    """A box flies through the camera position: before, during and after, the image stays finite."""
    v, t = box((0, 0, 0), (1, 1, 1))
    for tau_obs in (-20.0, -0.2, 0.0, 0.1, 0.3, 20.0):
        scene = Scene(camera=look_at_camera((0, 0, 0), (1, 0.1, 0)), meshes=[Mesh("Fly", v, t, velocity=Velocity((0.9, 0, 0)))],
                      lights=[lamp((0, 0, 3))], tau_obs=tau_obs)
        passes = render_image(scene, settings())
        assert_sane(passes)
        hit = passes["Doppler"][..., 0] > 0
        assert np.all(passes["Emission Time"][..., 0][hit] * 1.0 <= tau_obs / scene.light_speed + 1e-12)


def test_light_inside_a_closed_object_lights_nothing_outside():
    v, t = box((0, 0, 0), (2.1, 2.1, 2.1))  # (edges off the pixel centres: see docs/robustness.md)
    scene = Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), meshes=[Mesh("Crate", v, t)],
                  lights=[lamp((0, 0, 0))], world_color=(0, 0, 0))
    passes = render_image(scene, settings())
    assert_sane(passes)
    hit = passes["Doppler"][..., 0] > 0
    assert hit.sum() > 10
    assert np.all(passes["Combined"][..., :3][hit] == 0.0)  # the lamp is shut in: the crate is dark


@pytest.mark.parametrize("c", [0.0, -1.0, float("nan"), float("inf")])
def test_speed_of_light_must_be_positive(c):
    with pytest.raises(RenderError, match="speed of light"):
        render_image(ball_scene(light_speed=c), settings())


def test_huge_time_offset_keeps_precision():
    """Seen 10^6 light-seconds after the reference time, a moving ball looks as it does at 0 (pivot shifted)."""
    beta = np.array([0.6, 0.0, 0.0])
    v, t = uv_sphere((0, 0, 0), 1.0, 16, 8)
    images = []
    for big in (0.0, 1e6):
        pivot = beta * (5.0 - big)  # seen near the view centre about 5 light-seconds later
        # (camera off the mesh's symmetry planes: a ray exactly on an edge may pick either triangle)
        scene = Scene(camera=look_at_camera((0.013, -6, 0.021), (0.013, 0, 0.021)), lights=[lamp()],
                      meshes=[Mesh("Ball", v + pivot, t, velocity=Velocity(tuple(beta)), pivot=tuple(pivot))],
                      tau_obs=big, light_speed=1.0)
        images.append(render_image(scene, settings()))
    a, b = images
    assert (a["Doppler"] > 0).sum() > 10
    np.testing.assert_array_equal(a["Doppler"] > 0, b["Doppler"] > 0)
    np.testing.assert_allclose(a["Doppler"], b["Doppler"], rtol=1e-7)
    np.testing.assert_allclose(a["Combined"], b["Combined"], rtol=1e-5, atol=1e-6)
    hit = a["Doppler"] > 0
    # the passes are float32: at 10^6 s their resolution is 2^-4 s (documented)
    np.testing.assert_allclose(b["Emission Time"][hit] - 1e6, a["Emission Time"][hit], atol=0.07)


def many_velocities_scene(count, seed=7):
    rng = np.random.default_rng(seed)
    v, t = quad((0, 0, 0), (0.05, 0.05), normal_axis=1)
    meshes = []
    for i in range(count):
        centre = np.array([rng.uniform(-2, 2), 0.0, rng.uniform(-2, 2)])
        beta = rng.normal(size=3)
        beta *= rng.uniform(0, 0.9) / np.linalg.norm(beta)
        meshes.append(Mesh(f"Q{i}", v + centre, t, velocity=Velocity(tuple(beta)), pivot=tuple(centre)))
    return Scene(camera=look_at_camera((0, -6, 0), (0, 0, 0)), meshes=meshes, lights=[lamp()])


def test_a_thousand_distinct_velocities_finish():
    """1000 small quads, each with its own velocity (1000 rest frames): prepared and rendered (the time
    it takes is measured by tests/robustness/measure_velocities.py, not asserted)."""
    scene = many_velocities_scene(1000)
    renderer = prepare(scene, settings((8, 8)))
    assert len(renderer.frames.frames) >= 1000
    (tile,) = render_tiles(renderer)
    assert_sane(tile.passes)


_MANY = """
import sys
sys.path[:0] = {paths!r}
from test_robustness_core import many_velocities_scene, settings
from restframe_addon.core.prepared import prepare
renderer = prepare(many_velocities_scene(2000), settings((8, 8)))
print(len(renderer.frames.frames))
"""


def test_two_thousand_distinct_velocities_do_not_crash():
    """In a subprocess, so a crash fails this test instead of the whole run."""
    import subprocess
    import sys
    from pathlib import Path
    paths = [str(Path(__file__).parent), str(Path(__file__).parents[1] / "core"), str(Path(__file__).parents[2])]
    result = subprocess.run([sys.executable, "-c", _MANY.format(paths=paths)], capture_output=True, text=True,
                            timeout=300)
    assert result.returncode == 0, result.stderr[-2000:]
    assert int(result.stdout.split()[-1]) >= 2000

"""Each sample scene rendered small; its measured numbers against analytic predictions."""

import math
from pathlib import Path

import numpy as np
import pytest

import make_headlamp
import make_tiles
import samplelib as lib
import samplemeasure as sm

# float32 passes: D is quoted to ~1e-7 relative
D_TOL = 2e-6


def test_every_sample_is_imaged_when_the_pivot_event_arrives(samples_addon):
    """Saved frame, fps and light speed put the observation at the arrival of the light that left
    the moving assembly's pivot nearest the camera at the reference time (the paper's imaging time)."""
    import bpy

    stems = sorted(p.stem for p in Path(lib.HERE).glob("*.blend") if p.stem != "moving_sphere")
    assert len(stems) == 5 + 3 + 5 + 4 + 7
    for stem in stems:
        bpy.ops.wm.open_mainfile(filepath=f"{lib.HERE}/{stem}.blend", load_ui=False)
        scene = bpy.context.scene
        assert scene.render.engine == 'RESTFRAME'
        rf = scene.restframe
        tau_obs = (scene.frame_current - rf.reference_frame) * scene.render.fps_base / scene.render.fps * rf.light_speed
        meshes = [o for o in scene.objects if o.type == 'MESH']
        movers = [o for o in meshes if any(o.restframe.velocity)]
        assert movers or stem.endswith("rest"), stem
        camera = scene.camera.matrix_world.translation
        distance = min((camera - o.matrix_world.translation).length for o in (movers or meshes))
        assert scene.frame_current == lib.IMAGING_FRAME
        assert tau_obs == pytest.approx(distance, rel=1e-6), stem


def test_headlamp_axis_doppler_and_searchlight(render):
    """The axis ray always sees the plane's centre as it was at the reference time: D = gamma (1 + beta)
    (beta > 0 toward the camera) and, for a surface lit in its own frame, radiance D^4 times the rest one."""
    passes = {beta: render(stem, (33, 33), normalize_exposure=False)[0] for stem, beta in make_headlamp.VARIANTS.items()}
    rows = sm.headlamp(passes)
    for r in rows:
        assert r["D"] == pytest.approx(r["D_pred"], abs=D_TOL)
        assert r["ratio"] == pytest.approx(r["ratio_pred"], rel=2e-3)
    means = [r["mean"] for r in sorted(rows, key=lambda r: r["beta"])]
    assert means == sorted(means) and means[-1] > 100 * means[2] > 1e4 * means[0]


def test_headlamp_plane_edges_at_their_retarded_positions(render):
    """The plane's edge on the centre row is where its light left it: seen earlier (farther away
    when approaching, nearer when receding) than the centre.  The image shrinks toward the camera."""
    half = {}
    for stem, beta in make_headlamp.VARIANTS.items():
        passes, info = render(stem, (101, 101))
        row = lib.hit_mask(passes)[50]
        cols = np.flatnonzero(row)
        edge, _ = sm.retarded_point(info["position"], (5.0, 0.0, 0.0), (0.0, 0.0, beta), make_headlamp.CAMERA_DISTANCE)
        predicted = sm.project(info, edge)[0]
        assert abs(cols.max() - math.floor(predicted)) <= 1, stem
        assert abs((100 - cols.min()) - math.floor(predicted)) <= 1, stem  # symmetric
        half[beta] = predicted - 50
    assert half[0.9] < half[0.5] < half[0.0] < half[-0.5] < half[-0.9]
    assert half[0.9] < 0.85 * half[0.0]


@pytest.mark.parametrize("stem", list(make_tiles.VARIANTS))
def test_tile_doppler_range(render, stem):
    velocity = make_tiles.VARIANTS[stem]
    passes, info = render(stem, (63, 63))
    r = sm.tiles(passes, info, velocity)
    assert r["coverage"] > 0.6
    assert r["max_error"] < D_TOL
    lo, hi = r["field"]
    assert lo - 1e-6 <= r["measured"][0] and r["measured"][1] <= hi + 1e-6
    # the tiles reach the image edges: the measured range is that of the pixel centres (gaps aside)
    assert r["measured"] == pytest.approx(r["predicted_pixels"], abs=5e-3)
    if velocity[2]:
        assert r["measured"][1] == pytest.approx(lib.gamma(0.9) * 1.9, abs=D_TOL)  # the axis pixel
        assert lo == pytest.approx(sm.PAPER_RANGES[stem][0], abs=5e-3)  # our field of view is inferred from it


@pytest.mark.parametrize("stem", ["tiles_toward_0.9c", "tiles_sideways_0.8c"])
def test_tile_quantised_display(render, stem):
    """FACTOR mode, own range, 15 levels: grey rises with D and takes at most 15 values."""
    cont, _ = render(stem, (63, 63))
    quant, _ = render(stem + "_q15", (63, 63))
    hit = lib.hit_mask(quant)
    grey = quant["Combined"][..., 0][hit]
    d = quant["Doppler"][..., 0][hit]
    levels = np.unique(np.round(grey, 5))
    assert 8 <= len(levels) <= 15
    order = np.argsort(d)
    assert np.all(np.diff(grey[order]) >= -1e-6)
    lo, hi = d.min(), d.max()
    assert cont["Combined"][..., 0][hit] == pytest.approx((d - lo) / (hi - lo), abs=1e-4)


@pytest.mark.parametrize("kind", ["sideways", "toward"])
def test_bar_rows_doppler(render, kind):
    """Every pixel of every row: D = 1 / (gamma (1 + beta . d)) with that row's velocity."""
    passes, info = render(f"bars_{kind}", (63, 63))
    rows = sm.bars(passes, info, kind)
    assert all(r["pixels"] > 10 for r in rows)
    assert max(r["max_error"] for r in rows) < 5 * D_TOL
    if kind == "sideways":
        # sideways rows: D < 1 on average, decreasing with speed; the 0.99c row ~ 1/gamma = 0.14
        means = [np.mean(r["range"]) for r in rows[1:]]
        assert means == sorted(means, reverse=True)
        assert rows[-1]["range"][0] < 1 / lib.gamma(0.99) * 1.2 and rows[-1]["range"][1] > 1 / lib.gamma(0.99) * 0.8
    else:
        middle = rows[5]
        assert middle["range"][1] > 4.8 and rows[0]["range"] == (1.0, 1.0)


def test_bars_at_rest(render):
    passes, _ = render("bars_rest", (45, 45))
    d = passes["Doppler"][..., 0]
    assert np.all(d[d > 0] == 1.0)
    assert len(np.unique(np.rint(passes["Object Index"][..., 0]))) == 12  # 11 rows + void


def test_sphere_outline_is_a_circle_on_the_sky(render):
    passes, info = render("sphere_outline", (101, 101))
    r = sm.sphere_outline(passes, info)
    assert r["outline_pixels"] > 80
    assert r["rms_px"] < 0.5
    # its size and place on the sky: the rest-frame outline cone aberrated into the world frame
    assert abs(r["radius_deg"] - r["radius_pred_deg"]) < 0.3 * r["pixel_deg"]
    assert r["axis_error_px"] < 0.3
    # not merely an unchanged circle: contraction alone would squash the width to 0.44 of the height
    assert 0.9 < r["width_px"] / r["height_px"] < 1.1


def test_terrell_rotation_of_the_cube(render):
    passes, info = render("terrell_cube", (101, 101))
    r = sm.terrell_cube(passes)
    assert r["leading"] == 0 and r["trailing"] > 500
    assert r["ratio"] == pytest.approx(sm.terrell_prediction(info), rel=0.06)
    assert sm.terrell_prediction(info) == pytest.approx(0.9 * lib.gamma(0.9), rel=0.08)  # far-away limit

    def stop(scene):
        for obj in scene.objects:
            obj.restframe.velocity = (0.0, 0.0, 0.0)
    rest, _ = render("terrell_cube", (51, 51), prepare=stop)
    assert sm.terrell_cube(rest, 0.0)["trailing"] == 0


def test_mirror_shows_the_ball_where_the_longer_path_left_it(render):
    passes, info = render("mirror", (160, 90))
    r = sm.mirror(passes, info)
    assert r["direct_pixels"] > 20 and r["mirror_pixels"] > 10
    assert np.allclose(r["direct"], r["direct_pred"], atol=1.0)
    assert np.allclose(r["mirror"], r["mirror_pred"], atol=1.0)
    # the reflected light left 14.7 / c earlier: the reflection lags far behind the ball
    assert r["mirror_tau"] == pytest.approx(-14.7407, abs=1e-3)
    assert r["direct"][0] - r["mirror"][0] > 40


def test_glass_ball_in_front_of_moving_bars(render):
    passes, info = render("glass_bars", (121, 67))
    r = sm.glass_bars(passes, info)
    assert r["bars_pixels"] > 100 and r["bars_max_error"] < D_TOL
    assert r["glass_D"] == (1.0, 1.0)
    assert r["orange_in_glass"] > 0.02  # the bars are seen through the glass


def test_spectral_colour_reddens_receding_and_blues_approaching(render):
    c = {stem: sm.panel_colour(render(stem, (33, 33), spectral_samples=16)[0])
         for stem in ("spectral_away_0.9c", "spectral_away_0.6c", "spectral_rest", "spectral_toward_0.6c")}
    rest = c["spectral_rest"]
    assert c["spectral_away_0.6c"]["r"] > rest["r"] + 0.1
    assert c["spectral_away_0.9c"]["r"] > c["spectral_away_0.6c"]["r"]
    assert c["spectral_toward_0.6c"]["b"] > rest["b"] + 0.05
    for stem, beta in (("spectral_away_0.9c", -0.9), ("spectral_toward_0.6c", 0.6)):
        assert c[stem]["D"] == pytest.approx(lib.gamma(abs(beta)) * (1 + beta), abs=D_TOL)


def test_spectral_receding_dims_and_rest_matches_plain_rgb(render):
    raw = {stem: render(stem, (33, 33), spectral_samples=16, normalize_exposure=False)[0]
           for stem in ("spectral_away_0.9c", "spectral_rest")}
    lum = {k: float(v["Combined"][..., :3].mean()) for k, v in raw.items()}
    assert lum["spectral_away_0.9c"] < 0.05 * lum["spectral_rest"]
    plain, _ = render("spectral_rest", (33, 33), doppler_mode='OFF', normalize_exposure=False)
    spectral = raw["spectral_rest"]["Combined"][..., :3]
    rgb = plain["Combined"][..., :3]
    lit = rgb > 1e-3
    assert lit.sum() > 1000
    assert spectral[lit] == pytest.approx(rgb[lit], rel=1e-3)

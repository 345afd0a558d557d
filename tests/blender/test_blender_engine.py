"""The engine inside Blender: registration, properties, passes, errors and cancelling."""

import math

import bpy
import numpy as np
import pytest

import restframe_addon
from blender_helpers import add_camera, add_plane, render_exr
from restframe_addon import engine
from restframe_addon.core import workers
from restframe_addon.engine import OBJECT_INDEX_PASS, RestframeRenderEngine
from restframe_addon.properties import speed_of


def engine_available() -> bool:
    """Whether Blender accepts RESTFRAME as a scene's render engine (the menu is dynamic)."""
    render = bpy.data.scenes[0].render
    previous = render.engine
    try:
        render.engine = 'RESTFRAME'
    except TypeError:
        return False
    render.engine = previous
    return True


def registered():
    return (
        engine_available()
        and hasattr(bpy.types.Object, "restframe")
        and hasattr(bpy.types.Scene, "restframe")
        and hasattr(bpy.types, "RESTFRAME_OBJECT_PT_motion")
        and "restframe" in bpy.types.Object.bl_rna.properties
        and 'RESTFRAME' in bpy.types.RENDER_PT_format.COMPAT_ENGINES
    )


def unregistered():
    return not (
        engine_available()
        or hasattr(bpy.types.Object, "restframe")
        or hasattr(bpy.types.Scene, "restframe")
        or hasattr(bpy.types, "RESTFRAME_OBJECT_PT_motion")
        or "restframe" in bpy.types.Object.bl_rna.properties
        or 'RESTFRAME' in bpy.types.RENDER_PT_format.COMPAT_ENGINES
    )


def test_register_and_unregister_twice_in_a_row(addon):
    assert registered()
    try:
        for _ in range(2):
            restframe_addon.unregister()
            assert unregistered()
            restframe_addon.register()
            assert registered()
    finally:
        if not registered():
            restframe_addon.register()


def test_object_properties(scene):
    props = bpy.types.Object.bl_rna.properties["restframe"].fixed_type.properties
    velocity = props["velocity"]
    assert (velocity.type, velocity.subtype, velocity.array_length) == ('FLOAT', 'VELOCITY', 3)
    assert velocity.is_animatable and props["lorentz_factor"].is_animatable
    assert props["lorentz_factor"].hard_min == 0.0 and props["lorentz_factor"].default == 0.0
    for computed in ("beta", "gamma", "rapidity"):
        assert props[computed].is_readonly

    obj = add_plane(scene, velocity=(0.6, 0.0, 0.0))
    rf = obj.restframe
    assert (rf.beta, rf.gamma, rf.rapidity) == pytest.approx((0.6, 1.25, math.atanh(0.6)), rel=1e-6)
    rf.velocity = (0.0, 0.0, 1.0)
    rf.lorentz_factor = 1e6  # speed from gamma, velocity = direction only
    assert rf.gamma == 1e6 and rf.beta == pytest.approx(1.0, abs=1e-7)  # single precision display
    assert speed_of(rf.velocity, rf.lorentz_factor)[0] == pytest.approx(1.0 - 0.5e-12, abs=1e-15)
    assert rf.rapidity == pytest.approx(math.acosh(1e6))
    rf.lorentz_factor = 0.0
    rf.velocity = (0.9, 0.9, 0.0)
    assert math.isnan(rf.gamma)


def test_scene_properties(scene):
    props = bpy.types.Scene.bl_rna.properties["restframe"].fixed_type.properties
    expected = {"light_speed", "reference_frame", "samples", "max_bounces", "tile_size", "doppler_mode",
                "searchlight", "spectral_samples", "normalize_exposure", "doppler_range_auto", "doppler_range",
                "doppler_levels"}
    assert expected <= set(props.keys())
    assert [(item.identifier, item.value) for item in props["doppler_mode"].enum_items] == [
        ('OFF', 0), ('FACTOR', 1), ('SPECTRAL', 2)]
    assert props["light_speed"].hard_min > 0.0
    assert all(props[name].is_animatable for name in expected)


def test_velocity_is_keyframeable(scene):
    obj = add_plane(scene)
    obj.restframe.velocity = (0.0, 0.0, 0.0)
    obj.keyframe_insert("restframe.velocity", frame=1)
    obj.restframe.velocity = (0.8, 0.0, 0.0)
    obj.keyframe_insert("restframe.velocity", frame=11)
    scene.frame_set(11)
    assert obj.restframe.velocity[0] == pytest.approx(0.8)
    scene.frame_set(1)
    assert obj.restframe.velocity[0] == pytest.approx(0.0)
    scene.restframe.keyframe_insert("light_speed", frame=1)


def test_pass_names_follow_the_view_layer(scene, tmp_path):
    add_camera(scene)
    add_plane(scene)
    layer = scene.view_layers[0]
    layer.use_pass_z = layer.use_pass_normal = layer.use_pass_object_index = False
    assert set(render_exr(scene, tmp_path / "a.exr")) == {"Combined", "Doppler", "Emission Time", "Object Time"}
    layer.use_pass_z = layer.use_pass_normal = layer.use_pass_object_index = True
    assert set(render_exr(scene, tmp_path / "b.exr")) == {
        "Combined", "Depth", "Normal", OBJECT_INDEX_PASS, "Doppler", "Emission Time", "Object Time"}
    assert [p[0] for p in engine.list_render_passes(scene, layer)] == [
        "Combined", "Depth", "Normal", OBJECT_INDEX_PASS, "Doppler", "Emission Time", "Object Time"]


def test_blender_panels_show_for_restframe():
    for name in ("RENDER_PT_format", "RENDER_PT_output", "RENDER_PT_frame_range", "RENDER_PT_color_management",
                 "DATA_PT_camera", "DATA_PT_lens", "DATA_PT_context_light", "EEVEE_MATERIAL_PT_context_material",
                 "EEVEE_MATERIAL_PT_surface", "EEVEE_WORLD_PT_surface"):
        assert 'RESTFRAME' in getattr(bpy.types, name).COMPAT_ENGINES, name
    for name in ("DATA_PT_light", "NODE_DATA_PT_light", "RENDER_PT_freestyle", "DATA_PT_preview"):
        assert 'RESTFRAME' not in getattr(bpy.types, name).COMPAT_ENGINES, name


def test_invalid_velocity_fails_the_render_with_its_message(scene):
    add_camera(scene)
    add_plane(scene, "Tachyon", velocity=(0.0, 0.0, 1.2))
    with pytest.raises(RuntimeError, match="Tachyon: speed 1.2 c is not below the speed of light"):
        bpy.ops.render.render()


def test_a_single_factor_level_fails_the_render_with_its_message(scene):
    add_camera(scene)
    add_plane(scene, velocity=(0.5, 0.0, 0.0))
    scene.restframe.doppler_mode, scene.restframe.doppler_levels = 'FACTOR', 1
    with pytest.raises(RuntimeError, match="Levels must be 0 \\(continuous\\) or at least 2, not 1"):
        bpy.ops.render.render()


def test_missing_camera_fails_the_render(scene):
    add_plane(scene)
    with pytest.raises(RuntimeError, match="camera"):
        bpy.ops.render.render()


def test_unsupported_panorama_fails_the_render(scene):
    add_camera(scene, type='PANO', panorama_type='MIRRORBALL')
    add_plane(scene)
    with pytest.raises(RuntimeError, match="panorama type MIRRORBALL is not supported"):
        bpy.ops.render.render()


def test_cancel_during_render_leaves_tiles_unrendered(scene, tmp_path, monkeypatch):
    """Esc (test_break) mid-render: the render ends early, Blender stays usable."""
    add_camera(scene)
    add_plane(scene, size=1000.0, velocity=(0.3, 0.0, 0.0))
    scene.restframe.tile_size = 8  # 21x15 -> 3 x 2 tiles
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1
    tiles = []

    def counted_tiles(*args, **kwargs):
        for tile in engine_render_tiles(*args, **kwargs):
            tiles.append(tile)
            yield tile

    engine_render_tiles = engine.render_tiles
    monkeypatch.setattr(engine, "render_tiles", counted_tiles)
    # the user presses Esc once the first tile is on screen
    monkeypatch.setattr(RestframeRenderEngine, "should_stop", lambda self: bool(tiles))
    doppler = render_exr(scene, tmp_path / "cancelled.exr")["Doppler"][..., 0]
    assert len(tiles) == 1
    assert np.count_nonzero(doppler) == 8 * 8  # exactly the first tile
    monkeypatch.undo()
    doppler = render_exr(scene, tmp_path / "again.exr")["Doppler"][..., 0]
    assert np.count_nonzero(doppler) == doppler.size  # a second render right after works


def test_worker_processes_render_the_same_passes_as_threads(scene, tmp_path, monkeypatch):
    """F12 with Parallelism Processes (the default) and Threads: every pass bit for bit, and the
    same tiles streamed into the result."""
    add_camera(scene)
    add_plane(scene, velocity=(0.0, 0.5, 0.3))
    scene.view_layers[0].use_pass_z = scene.view_layers[0].use_pass_normal = True
    scene.restframe.samples, scene.restframe.tile_size = 3, 8
    scene.render.threads_mode, scene.render.threads = 'FIXED', 2
    streamed = []

    def counted_tiles(*args, **kwargs):
        for tile in engine_render_tiles(*args, **kwargs):
            streamed.append((tile.x0, tile.y0, tile.x1, tile.y1))
            yield tile

    engine_render_tiles = engine.render_tiles
    monkeypatch.setattr(engine, "render_tiles", counted_tiles)
    images, tiles = {}, {}
    for parallelism in ('PROCESSES', 'THREADS'):
        scene.restframe.parallelism = parallelism
        streamed.clear()
        images[parallelism] = render_exr(scene, tmp_path / f"{parallelism}.exr")
        tiles[parallelism] = sorted(streamed)
    assert len(workers.pool().pids) == 2  # the processes render ran in two workers, still running
    assert images['PROCESSES'].keys() == images['THREADS'].keys() and "Depth" in images['THREADS']
    for name, data in images['THREADS'].items():
        assert np.array_equal(images['PROCESSES'][name], data, equal_nan=True), name
    assert tiles['PROCESSES'] == tiles['THREADS'] and len(tiles['THREADS']) == 6  # 21x15: 3 x 2 tiles


def test_cancel_during_export_renders_nothing(scene, monkeypatch):
    """Esc while the scene is exported: no tracing starts and no error is shown."""
    add_camera(scene)
    for i in range(3):
        add_plane(scene, f"P{i}", location=(0, 0, -i))
    outcomes = []
    export_scene = engine.export.export_scene

    def spy_export(*args, **kwargs):
        try:
            return export_scene(*args, **kwargs)
        except BaseException as error:
            outcomes.append(type(error).__name__)
            raise

    monkeypatch.setattr(engine.export, "export_scene", spy_export)
    monkeypatch.setattr(engine, "prepare", lambda *args: outcomes.append("traced"))
    monkeypatch.setattr(RestframeRenderEngine, "should_stop", lambda self: True)
    # (no write_still: Blender itself skips writing a cancelled frame)
    assert bpy.ops.render.render() == {'FINISHED'}
    assert outcomes == ["ExportCancelled"]


def test_tiles_that_come_together_are_each_shown_at_once_and_their_progress_reported_once(scene, tmp_path,
                                                                                         monkeypatch):
    """Tiles the render loop hands over together (``Tile.more_ready``: worker processes finishing
    at once) are each written into Blender's result before the next is taken, and the progress
    is reported once, at the last of them; the image is the same bits; on Esc between them the
    progress still reaches the tiles written."""
    add_camera(scene)
    add_plane(scene, velocity=(0.0, 0.5, 0.3))
    scene.view_layers[0].use_pass_z = True
    scene.restframe.tile_size = 8  # 21x15 -> 3 x 2 tiles
    scene.render.threads_mode, scene.render.threads = 'FIXED', 1
    scene.restframe.parallelism = 'THREADS'  # every tile alone: the reference
    plain = render_exr(scene, tmp_path / "plain.exr")
    events, engines = [], []

    def paired_tiles(*args, **kwargs):  # tiles 1-2, 3-4, 5-6 come together
        for index, tile in enumerate(engine_render_tiles(*args, **kwargs)):
            tile.more_ready = index % 2 == 0
            yield tile
            events.append(f"written {engines[-1]._tiles_done}")  # the engine asks for the next tile

    def report_progress(self, status, done, total, started):
        events.append(f"progress {done}/{total}")
        return engine_report_progress(self, status, done, total, started)

    def should_stop(self):
        engines.append(self)
        return stopping(self)

    engine_render_tiles, engine_report_progress = engine.render_tiles, RestframeRenderEngine._report_progress
    monkeypatch.setattr(engine, "render_tiles", paired_tiles)
    monkeypatch.setattr(RestframeRenderEngine, "_report_progress", report_progress)
    monkeypatch.setattr(RestframeRenderEngine, "should_stop", should_stop)
    stopping = lambda self: False  # noqa: E731
    together = render_exr(scene, tmp_path / "together.exr")
    assert events == ["written 1", "progress 2/6", "written 2", "written 3", "progress 4/6", "written 4",
                      "written 5", "progress 6/6", "written 6"], events
    assert together.keys() == plain.keys() and "Depth" in plain
    for name, data in plain.items():
        assert np.array_equal(together[name], data, equal_nan=True), name
    events.clear()
    stopping = lambda self: bool(events)  # noqa: E731 (Esc once the first tile is written)
    render_exr(scene, tmp_path / "cancelled.exr")
    assert events == ["written 1", "progress 1/6"], events

"""The RESTframe render engine: F12, animation renders and ``blender -b ... -E RESTFRAME``.

``render()`` exports the evaluated depsgraph, then streams the core's tiles into
Blender's render result so the image fills in chunk by chunk.  Every failure is
reported with ``self.report({'ERROR'}, ...)``: Blender swallows exceptions raised
inside ``render()`` and would show a silent black image instead.

A render that stops early (Esc, :data:`STOP`, an error) still hands Blender a result
(Blender 5.0 crashes writing an EXR of a render that delivered none), and every render
leaves a :class:`RenderOutcome` (:func:`take_outcome`): the proof a headless caller needs
before it saves the image as a finished frame.
"""

from __future__ import annotations

import contextlib
import dataclasses
import sys
import threading
import time
import traceback
from dataclasses import dataclass

import bpy

from . import export
from .core.observer import proper_time
from .core.passes import BY_NAME
from .core.persistent import GeometryCache
from .core.prepared import prepare, prepare_view
from .core.render import render_tiles
from .core.validation import RenderError
from .core.workers import build_ahead

# Blender 5.0 renamed its object index pass ("IndexOB" before).
OBJECT_INDEX_PASS = "Object Index" if bpy.app.version >= (5, 0, 0) else "IndexOB"

# the render's metadata (Blender's stamp data: written into EXR headers and PNG text chunks)
STAMP_PROPER_TIME = "RESTframe Observer Proper Time"


def observer_stamp(scene) -> dict[str, str]:
    """Stamp fields of a rendered core scene: the camera's own clock at the observation event, in
    seconds from the reference time (its proper time on its world line)."""
    camera = scene.camera
    seconds = proper_time(scene.tau_obs, camera.velocity, camera.trajectory) / scene.light_speed
    return {STAMP_PROPER_TIME: f"{seconds:.12g} s"}


# Blender pass name -> the core's pass name
_CORE_PASS = {OBJECT_INDEX_PASS: "IndexOB"}
_BLENDER_PASS = {core: blender for blender, core in _CORE_PASS.items()}


def list_render_passes(scene, view_layer):
    """(name, channel ids, type) of every pass a render of this view layer produces: Combined,
    then the core's (``export.core_passes``: Blender's enabled ones, RESTframe's own always)."""
    yield ("Combined", "RGBA", 'COLOR')
    for name in export.core_passes(view_layer):
        yield (_BLENDER_PASS.get(name, name), BY_NAME[name].channels, BY_NAME[name].kind)


# Set by the headless layer when SIGINT or SIGTERM arrives during a render (headless.py):
# the render stops at its next check, as on Esc.
STOP = threading.Event()

# A Ctrl-C (KeyboardInterrupt) that landed in an engine callback other than render, which Blender
# prints and drops: the next render fails as interrupted instead of finishing.
_PENDING_INTERRUPT = threading.Event()


@contextlib.contextmanager
def _interrupt_kept_for_render():
    try:
        yield
    except KeyboardInterrupt:
        _PENDING_INTERRUPT.set()


@dataclass(frozen=True)
class RenderOutcome:
    """What a render delivered to Blender's result."""

    tiles: int  # tiles written into the result
    total: int  # tiles the image has (0: the render stopped before it knew)
    stopped: bool  # ended early: Esc, STOP, an interrupt or an error

    @property
    def complete(self) -> bool:
        return not self.stopped and self.total > 0 and self.tiles == self.total


_last_outcome: RenderOutcome | None = None


def take_outcome() -> RenderOutcome | None:
    """The outcome of the last render in this process (None if none ran since the last call)."""
    global _last_outcome
    outcome, _last_outcome = _last_outcome, None
    return outcome


class RestframeRenderEngine(bpy.types.RenderEngine):
    bl_idname = "RESTFRAME"
    bl_label = "RESTframe"
    bl_use_preview = False  # material previews would need the full tracer per thumbnail
    bl_use_postprocess = True  # compositor and sequencer run on our result
    bl_use_eevee_viewport = True  # Material Preview / Rendered viewport shading use EEVEE
    bl_use_shading_nodes_custom = False  # Blender's own shader nodes define materials

    # Blender 5.0 needs the full signature, or the engine fails silently (empty image).
    def __init__(self, *args, **kwargs):
        with _interrupt_kept_for_render():
            super().__init__(*args, **kwargs)
        # Blender keeps one engine for the frames of an animation (and later F12s) while the
        # scene's Persistent Data is on: unchanged rest-frame geometry is then built only once
        self.geometry_cache = GeometryCache()

    def _persistent_data(self, depsgraph) -> GeometryCache | None:
        """The geometry kept from earlier renders, if the scene's Persistent Data is on (else it is
        dropped, and every render builds afresh)."""
        if depsgraph.scene.render.use_persistent_data:
            return self.geometry_cache
        self.geometry_cache.clear()
        return None

    def should_stop(self) -> bool:
        """Esc pressed (or STOP set): checked between exported objects, tiles and sample batches."""
        return STOP.is_set() or self.test_break()

    def update_render_passes(self, scene=None, renderlayer=None):
        with _interrupt_kept_for_render():
            for name, channel_ids, channel_type in list_render_passes(scene, renderlayer):
                self.register_pass(scene, renderlayer, name, len(channel_ids), channel_ids, channel_type)

    def _prepare(self, scene, settings, first_view=None, geometry_cache=None):
        """``prepare(...)`` (or, given the first view's prepared scene, ``prepare_view``) in a
        worker thread, polled for Esc every 50 ms; ``geometry_cache``: Persistent Data.

        The build checks Esc between its steps, but polling needs the GIL, which embree's BVH
        build holds throughout when it goes through embreex (about 0.4 s for a million
        triangles; handed to embree directly it lets go): on Esc the render returns within
        that, and the abandoned build stops at its next check.  None when cancelled.
        """
        cancelled = threading.Event()
        box = {}

        def work():
            try:
                box["prepared"] = (prepare(scene, settings, cancelled.is_set, geometry_cache) if first_view is None
                                   else prepare_view(first_view, scene.camera, cancelled.is_set))
            except BaseException as error:  # handed to the main thread
                box["error"] = error

        worker = threading.Thread(target=work, name="restframe-prepare", daemon=True)
        worker.start()
        while worker.is_alive():
            worker.join(0.05)
            if worker.is_alive() and self.should_stop():
                cancelled.set()
                return None
        if "error" in box:
            raise box["error"]
        return None if self.should_stop() else box["prepared"]

    def render(self, depsgraph):
        global _last_outcome
        self._tiles_done = self._tiles_total = self._tiles_reported = 0
        failed = False
        try:
            if _PENDING_INTERRUPT.is_set():  # Ctrl-C before this render began (an earlier callback)
                _PENDING_INTERRUPT.clear()
                raise KeyboardInterrupt
            self._render(depsgraph)
        except KeyboardInterrupt:
            # Ctrl-C with Python's default handler (a script calling bpy.ops.render.render):
            # Blender would swallow it and return the partial image as finished; an error makes
            # the operator raise instead
            failed = True
            self.report({'ERROR'}, "RESTframe: render interrupted (KeyboardInterrupt): the image is incomplete")
        except Exception as error:  # anything unexpected must still reach the user
            failed = True
            traceback.print_exc(file=sys.stderr)
            self.report({'ERROR'}, f"RESTframe: {type(error).__name__}: {error}")
        finally:
            if self._tiles_done == 0:  # an empty result: with none, Blender 5.0 crashes saving an EXR
                self.end_result(self.begin_result(0, 0, self.resolution_x, self.resolution_y,
                                                  layer=depsgraph.view_layer.name))
            _last_outcome = RenderOutcome(self._tiles_done, self._tiles_total, failed or self.should_stop())

    def _render(self, depsgraph):
        started = time.monotonic()
        view_layer = depsgraph.view_layer
        self.update_stats("", "RESTframe | Exporting scene")
        try:
            scene, settings = export.export_scene(
                depsgraph,
                self.camera_override,
                resolution=(self.resolution_x, self.resolution_y),
                should_stop=self.should_stop,
                warn=lambda message: self.report({'WARNING'}, f"RESTframe: {message}"),
            )
            if self.should_stop():
                return
            views = export.render_views(depsgraph.scene_eval)
            persistent = self._persistent_data(depsgraph)
            if not views:
                self._render_view(scene, settings, view_layer, None, started, geometry_cache=persistent)
                return
            camera_object = (self.camera_override or depsgraph.scene_eval.camera).evaluated_get(depsgraph)
            first = None
            for view in views:  # each eye is its own camera and observation event; the rest frames are shared
                # while the eyes move alike (not on an accelerating assembly: core.prepared.prepare_view)
                self.active_view_set(view)
                camera = export.view_camera(scene.camera, camera_object, depsgraph.scene_eval,
                                            self.camera_model_matrix(camera_object, use_spherical_stereo=False),
                                            self.camera_shift_x(camera_object, use_spherical_stereo=False))
                first = self._render_view(dataclasses.replace(scene, camera=camera), settings, view_layer, view,
                                          started, first, persistent)
                if first is None:
                    return
        except export.ExportCancelled:
            return
        except (export.ExportError, RenderError) as error:
            self.report({'ERROR'}, f"RESTframe: {error}")
            return

    def _render_view(self, scene, settings, view_layer, view, started, first_view=None, geometry_cache=None):
        """Prepare (from ``first_view``'s prepared scene if given) and render one view (None: the
        only one) into Blender's result; its prepared scene, or None once stopped."""
        self.update_stats("", "RESTframe | Building rest frames")
        if first_view is None:
            build_ahead(scene, settings)  # worker processes build it while this process prepares it
        prepared = self._prepare(scene, settings, first_view, geometry_cache)
        if prepared is None:
            return None
        if first_view is None:  # the views share the rest frames and their warnings: said once
            for message in prepared.warnings:
                self.report({'WARNING'}, f"RESTframe: {message}")

        x_offset, y_offset = prepared.region[:2]
        total = self._tiles_total = len(prepared.tiles())
        triangles = sum(len(mesh.triangles) for mesh in scene.meshes)
        tiles = render_tiles(prepared, self.should_stop,  # in worker processes or threads (Scene.restframe.parallelism)
                             warn=lambda message: self.report({'WARNING'}, f"RESTframe: {message}"))
        layer, view_name, filled = view_layer.name, view or "", None
        status = (f"RESTframe | {len(scene.meshes)} objects, {triangles} triangles | "
                  f"{'' if view is None else f'View {view} | '}Tile ")
        for done, tile in enumerate(tiles, start=1):
            result = self.begin_result(tile.x0 - x_offset, tile.y0 - y_offset,
                                       tile.x1 - tile.x0, tile.y1 - tile.y0, layer=layer, view=view_name)
            passes = result.layers[0].passes
            if filled is None:  # every tile's result has the same passes: read their names once
                filled = _filled_passes(passes, tile.passes)
            for index, name in filled:
                passes[index].rect.foreach_set(tile.passes[name].ravel())
            self.end_result(result)
            self._tiles_done = done
            if not tile.more_ready:  # shown at once; the progress once for the tiles that came together
                self._report_progress(status, done, total, started)
        if 0 < self._tiles_done != self._tiles_reported:  # stopped before the last of tiles that came together
            self._report_progress(status, self._tiles_done, total, started)
        result = self.get_result()
        for field, value in observer_stamp(scene).items():
            result.stamp_data_add_field(field, value)
        return None if self.should_stop() else prepared

    def _report_progress(self, status: str, done: int, total: int, started: float):
        """Blender's progress bar and status line: ``done`` of ``total`` tiles written."""
        self._tiles_reported = done
        self.update_progress(done / total)
        self.update_stats("", f"{status}{done}/{total} | {time.monotonic() - started:.1f} s")


def _filled_passes(render_passes, core_passes: dict) -> list[tuple[int, str]]:
    """(index in a tile's result, core pass name) of each of Blender's passes that a tile of the
    core fills: the core has it, with the same channels."""
    filled = []
    for index, render_pass in enumerate(render_passes):
        name = _CORE_PASS.get(render_pass.name, render_pass.name)
        if name in core_passes and core_passes[name].shape[2] == render_pass.channels:
            filled.append((index, name))
    return filled


classes = (RestframeRenderEngine,)


register, unregister = bpy.utils.register_classes_factory(classes)

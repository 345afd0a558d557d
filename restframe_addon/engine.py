"""The RESTframe render engine: F12, animation renders and ``blender -b ... -E RESTFRAME``.

``render()`` exports the evaluated depsgraph, then streams the core's tiles into
Blender's render result so the image fills in chunk by chunk.  Every failure is
reported with ``self.report({'ERROR'}, ...)``: Blender swallows exceptions raised
inside ``render()`` and would show a silent black image instead.
"""

from __future__ import annotations

import sys
import threading
import time
import traceback

import bpy

from . import export
from .core.passes import BY_NAME
from .core.prepared import prepare
from .core.render import render_tiles
from .core.validation import RenderError

# Blender 5.0 renamed its object index pass ("IndexOB" before).
OBJECT_INDEX_PASS = "Object Index" if bpy.app.version >= (5, 0, 0) else "IndexOB"

# Blender pass name -> the core's pass name
_CORE_PASS = {OBJECT_INDEX_PASS: "IndexOB"}
_BLENDER_PASS = {core: blender for blender, core in _CORE_PASS.items()}


def list_render_passes(scene, view_layer):
    """(name, channel ids, type) of every pass a render of this view layer produces: Combined,
    then the core's (``export.core_passes``: Blender's enabled ones, RESTframe's own always)."""
    yield ("Combined", "RGBA", 'COLOR')
    for name in export.core_passes(view_layer):
        yield (_BLENDER_PASS.get(name, name), BY_NAME[name].channels, BY_NAME[name].kind)


class RestframeRenderEngine(bpy.types.RenderEngine):
    bl_idname = "RESTFRAME"
    bl_label = "RESTframe"
    bl_use_preview = False  # material previews would need the full tracer per thumbnail
    bl_use_postprocess = True  # compositor and sequencer run on our result
    bl_use_eevee_viewport = True  # Material Preview / Rendered viewport shading use EEVEE
    bl_use_shading_nodes_custom = False  # Blender's own shader nodes define materials

    # Blender 5.0 needs the full signature, or the engine fails silently (empty image).
    def __init__(self, *args, **kwargs):
        super().__init__(*args, **kwargs)

    def should_stop(self) -> bool:
        """Esc pressed: checked between exported objects and between tiles."""
        return self.test_break()

    def update_render_passes(self, scene=None, renderlayer=None):
        for name, channel_ids, channel_type in list_render_passes(scene, renderlayer):
            self.register_pass(scene, renderlayer, name, len(channel_ids), channel_ids, channel_type)

    def _prepare(self, scene, settings):
        """``prepare(...)`` in a worker thread, polled for Esc every 50 ms.

        The build checks Esc between pieces of 2**14 triangles, but polling needs the GIL,
        which each frame's embree BVH build holds throughout (about 0.4 s for a million
        triangles): on Esc the render returns within that, and the abandoned build stops at
        its next check.  None when cancelled.
        """
        cancelled = threading.Event()
        box = {}

        def work():
            try:
                box["prepared"] = prepare(scene, settings, cancelled.is_set)
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
        try:
            self._render(depsgraph)
        except Exception as error:  # anything unexpected must still reach the user
            traceback.print_exc(file=sys.stderr)
            self.report({'ERROR'}, f"RESTframe: {type(error).__name__}: {error}")

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
            self.update_stats("", "RESTframe | Building rest frames")
            prepared = self._prepare(scene, settings)
            if prepared is None:
                return
        except export.ExportCancelled:
            return
        except (export.ExportError, RenderError) as error:
            self.report({'ERROR'}, f"RESTframe: {error}")
            return
        for message in prepared.warnings:
            self.report({'WARNING'}, f"RESTframe: {message}")

        x_offset, y_offset = prepared.region[:2]
        total = len(prepared.tiles())
        triangles = sum(len(mesh.triangles) for mesh in scene.meshes)
        for done, tile in enumerate(render_tiles(prepared, self.should_stop), start=1):
            result = self.begin_result(tile.x0 - x_offset, tile.y0 - y_offset,
                                       tile.x1 - tile.x0, tile.y1 - tile.y0, layer=view_layer.name)
            for render_pass in result.layers[0].passes:
                data = tile.passes.get(_CORE_PASS.get(render_pass.name, render_pass.name))
                if data is not None and data.shape[2] == render_pass.channels:
                    render_pass.rect.foreach_set(data.ravel())
            self.end_result(result)
            self.update_progress(done / total)
            self.update_stats("", f"RESTframe | {len(scene.meshes)} objects, {triangles} triangles | "
                              f"Tile {done}/{total} | {time.monotonic() - started:.1f} s")


classes = (RestframeRenderEngine,)


register, unregister = bpy.utils.register_classes_factory(classes)

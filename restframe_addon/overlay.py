"""Velocity arrows in the 3D viewport (RESTframe engine, Scene.restframe.show_velocity).

An arrow starts at the object's origin and is as long as the distance the object
covers in one second of scene time (speed x light_speed), so its length reads in
scene units.  Drawn with the ``gpu`` module from a SpaceView3D draw handler;
in background mode the handler is registered but never called.
"""

from __future__ import annotations

import math

import bpy
import numpy as np

from .properties import speed_of

COLOR = (1.0, 0.55, 0.1, 1.0)
HEAD = 0.15  # arrow head length as a fraction of the arrow
_handle = None


def arrow_segments(scene, view_layer=None) -> np.ndarray:
    """(N, 2, 3) line segments (shaft and two head strokes) for every visible moving object."""
    segments = []
    for obj in scene.objects:
        rf = obj.restframe
        if not rf.is_moving or (view_layer is not None and not obj.visible_get(view_layer=view_layer)):
            continue
        beta = speed_of(rf.velocity, rf.lorentz_factor)[0]
        direction = np.array(rf.velocity, dtype=np.float64)
        norm = np.linalg.norm(direction)
        if math.isnan(beta) or norm == 0.0:
            continue
        direction /= norm
        start = np.array(obj.matrix_world.translation, dtype=np.float64)
        length = beta * scene.restframe.light_speed
        end = start + direction * length
        side = np.cross(direction, (0.0, 0.0, 1.0) if abs(direction[2]) < 0.9 else (1.0, 0.0, 0.0))
        side /= np.linalg.norm(side)
        back = end - direction * (HEAD * length)
        segments += [(start, end), (end, back + side * (0.5 * HEAD * length)), (end, back - side * (0.5 * HEAD * length))]
    return np.array(segments, dtype=np.float32).reshape(-1, 2, 3)


def draw_arrows():
    context = bpy.context
    scene = context.scene
    if scene.render.engine != 'RESTFRAME' or not scene.restframe.show_velocity:
        return
    segments = arrow_segments(scene, context.view_layer)
    if not len(segments):
        return
    import gpu
    from gpu_extras.batch import batch_for_shader

    shader = gpu.shader.from_builtin('POLYLINE_UNIFORM_COLOR')
    batch = batch_for_shader(shader, 'LINES', {"pos": segments.reshape(-1, 3)})
    shader.uniform_float("viewportSize", gpu.state.viewport_get()[2:])
    shader.uniform_float("lineWidth", 2.0)
    shader.uniform_float("color", COLOR)
    gpu.state.blend_set('ALPHA')
    batch.draw(shader)
    gpu.state.blend_set('NONE')


def register():
    global _handle
    _handle = bpy.types.SpaceView3D.draw_handler_add(draw_arrows, (), 'WINDOW', 'POST_VIEW')


def unregister():
    global _handle
    if _handle is not None:
        bpy.types.SpaceView3D.draw_handler_remove(_handle, 'WINDOW')
        _handle = None

"""Evaluated Blender data -> :mod:`restframe_addon.core.scene`, one module per kind of data.

``scene`` walks the depsgraph and calls ``motion`` (velocities, animated world lines),
``materials``, ``meshes``, ``lights`` (and the world), ``camera`` and ``settings``
(render settings, resolution, border, passes).  What the engine and the CLI use is
named here.
"""

from .camera import render_views, view_camera
from .errors import ExportCancelled, ExportError
from .scene import export_scene
from .settings import core_passes, full_resolution

__all__ = ("ExportCancelled", "ExportError", "core_passes", "export_scene", "full_resolution", "render_views",
           "view_camera")

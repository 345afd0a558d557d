"""Blender extension entry point.

The manifest (blender_manifest.toml) sits at the repository root, so the
extension's root package is this directory; the add-on itself lives in
``restframe_addon`` (importable on its own, e.g. ``python -m restframe_addon``).
"""

from .restframe_addon import register, unregister

__all__ = ["register", "unregister"]

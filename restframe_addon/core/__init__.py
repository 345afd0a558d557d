"""RESTframe core: relativistic REST-frame ray tracing in plain numpy + embreex.

Nothing in this package imports ``bpy``: the Blender layer exports a
:class:`~restframe_addon.core.scene.Scene`, prepares it once
(:func:`~restframe_addon.core.prepared.prepare`) and renders the prepared scene's
tiles (:func:`~restframe_addon.core.render.render_tiles`).
"""

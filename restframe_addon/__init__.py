"""RESTframe: a Blender render engine that shows special relativity.

Objects given a velocity near the speed of light are rendered as a camera would
see them: light-travel delay, aberration, Terrell rotation, Doppler and
searchlight effects.  The tracer (``core``) is plain numpy + embreex and never
imports ``bpy``; this package is the Blender layer around it (Cycles' add-on is
the model: ``engine``, ``properties``, ``ui``, plus ``export``).

``bpy`` is only imported when registering, so ``restframe_addon.core`` stays
usable without Blender.
"""


def register():
    from . import engine, overlay, properties, ui

    properties.register()
    engine.register()
    ui.register()
    overlay.register()


def unregister():
    from . import engine, overlay, properties, ui
    from .core import workers

    workers.shutdown()  # the workers run this version's code
    overlay.unregister()
    ui.unregister()
    engine.unregister()
    properties.unregister()

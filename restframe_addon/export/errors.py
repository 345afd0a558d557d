"""The exporter's two ways to stop: the scene cannot be rendered, or the user cancelled."""


class ExportError(ValueError):
    """The Blender scene cannot be rendered as it is; the message names what to fix."""


class ExportCancelled(Exception):
    """The user pressed Esc (``should_stop`` became true) during export."""


"""Rendering without a user interface: open a .blend, configure its output, render a frame
(or a region of it) and write the image atomically.

Shared by the command line (``__main__``) and the Dask render child (``distributed``), so a
frame is rendered and written the same way wherever it runs.  One render is described by a
:class:`RenderSpec` (plain data: it crosses process boundaries as JSON).

Interrupts: inside :func:`interruptible`, SIGINT (Ctrl-C) and SIGTERM never raise inside
Blender's render call (Blender would swallow the exception and hand back a partly black image
as if it were finished).  During a render they ask the engine to stop at its next check
(between exported objects, tiles and sample batches); anywhere else they raise
:class:`Interrupted` at once.  A frame is written only when the engine reports every tile
rendered (``engine.take_outcome``), so an interrupted frame is never on disk as complete.

bpy is imported on use only: the Dask client imports this module for its writer.
"""

from __future__ import annotations

import contextlib
import os
import signal
import threading
from dataclasses import asdict, dataclass
from typing import Callable

from .core.validation import RenderError, check_region

# extension -> (file format, multilayer)
FORMATS = {
    ".png": ("PNG", False),
    ".jpg": ("JPEG", False),
    ".jpeg": ("JPEG", False),
    ".tif": ("TIFF", False),
    ".tiff": ("TIFF", False),
    ".exr": ("OPEN_EXR_MULTILAYER", True),
}

STOP_SIGNALS = (signal.SIGINT, signal.SIGTERM)


class CommandError(Exception):
    """A problem with the command line, the file or the render, reported without a traceback."""


class Interrupted(BaseException):
    """SIGINT or SIGTERM arrived: stop everything (a BaseException, like KeyboardInterrupt, so
    no ``except Exception`` on the way keeps going)."""

    def __init__(self, signum: int, frame: int | None = None):
        self.signum, self.frame = signum, frame
        super().__init__(self.message())

    @property
    def status(self) -> int:
        """The conventional exit status of a process stopped by this signal (130 for Ctrl-C)."""
        return 128 + self.signum

    @property
    def signal_name(self) -> str:
        return signal.Signals(self.signum).name

    def message(self) -> str:
        where = f": frame {self.frame} was not written" if self.frame is not None else ""
        return f"interrupted by {self.signal_name}{where}"


@dataclass(frozen=True)
class RenderSpec:
    """One render: which frame of which .blend, with what overrides, written where."""

    blend: str
    output: str  # the file to write; its extension picks the format (none: the scene's own)
    frame: int
    scene: str | None = None  # default: the file's active scene
    samples: int | None = None
    percentage: int | None = None
    region: tuple[int, int, int, int] | None = None  # pixel rectangle, X1/Y1 exclusive
    threads: int | None = None  # cores the render may use (tile worker processes or threads); None: the scene's setting

    def to_json(self) -> dict:
        return asdict(self)

    @classmethod
    def from_json(cls, data: dict) -> "RenderSpec":
        region = data.get("region")
        return cls(**dict(data, region=tuple(region) if region is not None else None))


# --------------------------------------------------------------------------- signals
_received: list[int] = []  # signals that arrived inside interruptible(), in order
_rendering = False  # inside bpy.ops.render.render: a signal only asks the engine to stop


def _on_signal(signum, _frame):
    _received.append(signum)
    if _rendering:
        from . import engine

        engine.STOP.set()
    else:
        raise Interrupted(signum)


@contextlib.contextmanager
def interruptible():
    """SIGINT and SIGTERM stop the work cleanly (see the module's docstring) while inside."""
    if threading.current_thread() is not threading.main_thread():
        yield  # signal handlers can only be set on the main thread, where the signals arrive
        return
    _received.clear()
    previous = {signum: signal.signal(signum, _on_signal) for signum in STOP_SIGNALS}
    try:
        yield
    finally:
        for signum, handler in previous.items():
            signal.signal(signum, handler)


@contextlib.contextmanager
def _signals_stop_the_render(frame: int):
    """Inside: a signal sets ``engine.STOP``; on leaving, any signal raises :class:`Interrupted`."""
    global _rendering
    from . import engine

    if _received:  # arrived where Blender swallowed the exception (a callback during loading)
        raise Interrupted(_received[0], frame)
    engine.STOP.clear()
    _rendering = True
    try:
        yield
    finally:
        _rendering = False
    if _received:
        raise Interrupted(_received[0], frame)


# --------------------------------------------------------------------------- writing
def write_atomically(path: str, write: Callable[[str], None]) -> None:
    """``write(temporary_path)`` then rename it to ``path``: readers see the old file or the
    whole new one, never half of it, and a failed or interrupted write leaves nothing behind.

    The temporary file is created in ``path``'s folder (so the rename is atomic) with the
    permissions of any new file under the process's umask."""
    partial = _create_partial(path)
    try:
        write(partial)
        os.replace(partial, path)
    finally:
        if os.path.exists(partial):
            os.remove(partial)


def check_writable(paths) -> None:
    """Fail now, not after the render, when an output cannot be written (a folder, under a
    file, no permission): creates and removes an empty temporary file in each folder."""
    by_folder = {}
    for path in paths:
        _refuse_folder(path)
        by_folder.setdefault(os.path.dirname(os.path.abspath(path)), path)
    for path in by_folder.values():
        os.remove(_create_partial(path))


def _refuse_folder(path: str) -> None:
    if os.path.isdir(path):
        raise CommandError(f"{path}: is a folder, not an image file name")


def _create_partial(path: str) -> str:
    """A new empty file beside ``path`` (mode 0666 less the umask), or a clear error."""
    directory = os.path.dirname(os.path.abspath(path))
    try:
        os.makedirs(directory, exist_ok=True)
    except (FileExistsError, NotADirectoryError):
        raise CommandError(f"{path}: cannot write there: {_existing_ancestor(directory)} is a file, "
                           "not a folder") from None
    except OSError as error:
        raise CommandError(f"{path}: cannot create its folder: {error.strerror}") from None
    _refuse_folder(path)
    stem, ext = os.path.splitext(os.path.basename(path))
    while True:
        partial = os.path.join(directory, f".{stem}.partial-{os.getpid()}-{os.urandom(4).hex()}{ext}")
        try:
            os.close(os.open(partial, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666))
            return partial
        except FileExistsError:
            continue
        except OSError as error:
            raise CommandError(f"{path}: cannot write in {directory}: {error.strerror}") from None


def _existing_ancestor(path: str) -> str:
    while not os.path.exists(path):
        path = os.path.dirname(path)
    return path


def write_bytes(path: str, data: bytes) -> None:
    """Write ``data`` to ``path`` atomically, flushed to disk before the rename."""

    def write(partial):
        with open(partial, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())

    write_atomically(path, write)


# --------------------------------------------------------------------------- the scene
def open_blend(path: str, scene_name: str | None = None):
    """Load FILE.blend with the add-on registered and RESTframe as its engine."""
    import bpy

    import restframe_addon

    if not hasattr(bpy.types.Scene, "restframe"):
        restframe_addon.register()
    if not os.path.isfile(path):
        raise CommandError(f"{path}: no such .blend file")
    try:
        bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    except RuntimeError as error:
        raise CommandError(f"{path}: not a readable .blend file ({_blender_message(error)})") from None
    scene = bpy.data.scenes.get(scene_name) if scene_name else bpy.context.scene
    if scene is None:
        raise CommandError(f"{path}: no scene named {scene_name!r} "
                           f"(scenes: {', '.join(s.name for s in bpy.data.scenes)})")
    scene.render.engine = 'RESTFRAME'
    return scene


def _blender_message(error: RuntimeError) -> str:
    message = str(error).strip()
    return message[len("Error: "):] if message.startswith("Error: ") else message


def apply_overrides(scene, samples: int | None = None, percentage: int | None = None,
                    threads: int | None = None) -> None:
    if samples is not None:
        scene.restframe.samples = samples
    if percentage is not None:
        scene.render.resolution_percentage = percentage
    if threads is not None:
        scene.render.threads_mode = 'FIXED'
        scene.render.threads = threads


def configure_output(scene, out: str) -> str:
    """Set the scene's image format from OUT's extension; returns the extension to write."""
    ext = os.path.splitext(out)[1].lower()
    settings = scene.render.image_settings
    if not ext:
        return scene.render.file_extension
    if ext not in FORMATS:
        raise CommandError(f"unknown output extension {ext!r}: use one of {', '.join(sorted(FORMATS))}")
    file_format, multilayer = FORMATS[ext]
    if hasattr(settings, "media_type"):  # Blender 5.0+: choose the media type first
        settings.media_type = 'MULTI_LAYER_IMAGE' if multilayer else 'IMAGE'
        if not multilayer:
            settings.file_format = file_format
    else:
        settings.file_format = file_format
    if multilayer:
        check_exr_pixel_aspect(scene, f"{out}: ")
        settings.color_depth = '32'  # full float: pass values (Doppler, times) are quotable
    else:
        settings.color_mode = 'RGBA' if scene.render.film_transparent and file_format != "JPEG" else 'RGB'
    return ext


def check_exr_pixel_aspect(scene, where: str = "", instead: str = "write .png, .jpg or .tif") -> None:
    """Blender 5.0's multilayer EXR writer fails on a pixel aspect other than 1 ("Conflicting
    attributes ... pixelAspectRatio", Cycles' renders too): say so before rendering."""
    import bpy

    x, y = scene.render.pixel_aspect_x, scene.render.pixel_aspect_y
    if x != y and bpy.app.version >= (5, 0, 0):
        raise CommandError(f"{where}Blender {bpy.app.version_string} cannot write a multilayer EXR with a pixel "
                           f"aspect of {x:g}:{y:g} (its EXR writer fails): set Pixel Aspect X and Y equal, or {instead}")


def set_region(scene, region: tuple[int, int, int, int]) -> None:
    """Render only this pixel rectangle (Blender's render border, cropped to it)."""
    from .export import full_resolution

    width, height = full_resolution(scene)
    x0, y0, x1, y1 = region
    try:
        check_region(region, (width, height))
    except RenderError as error:
        raise CommandError(str(error)) from error
    render = scene.render
    render.use_border = True
    render.use_crop_to_border = True

    # fractions a quarter pixel past each edge: truncation (Blender's and the exporter's)
    # gives back the edge exactly despite the single-precision border properties
    def edge(pixels, size):
        return 1.0 if pixels >= size else (pixels + 0.25) / size

    render.border_min_x, render.border_max_x = edge(x0, width), edge(x1, width)
    render.border_min_y, render.border_max_y = edge(y0, height), edge(y1, height)


# --------------------------------------------------------------------------- rendering
def render_frame(scene, frame: int, path: str):
    """Render one frame and write it to ``path`` atomically; returns the engine's outcome.

    Nothing is written unless every tile was rendered: an interrupt raises
    :class:`Interrupted`, any other early stop a :class:`CommandError`."""
    import bpy

    from . import engine

    engine.take_outcome()  # forget any earlier render's
    with _signals_stop_the_render(frame):
        scene.frame_set(frame)
        try:
            bpy.ops.render.render(write_still=False, scene=scene.name)
        except RuntimeError as error:
            raise CommandError(f"frame {frame}: {str(error).strip()}") from None
    outcome = engine.take_outcome()
    if outcome is None or not outcome.complete:
        done = f"{outcome.tiles} of {outcome.total} tiles" if outcome is not None else "no RESTframe render ran"
        raise CommandError(f"frame {frame}: the render stopped before it was complete ({done}); nothing written")
    write_atomically(path, lambda partial: _save_render(bpy.data.images["Render Result"], scene, partial))
    return outcome


def render(spec: RenderSpec):
    """Open ``spec.blend`` afresh, render the frame (or region) and write ``spec.output``."""
    scene = open_blend(spec.blend, spec.scene)
    apply_overrides(scene, spec.samples, spec.percentage, spec.threads)
    configure_output(scene, spec.output)
    if spec.region is not None:
        set_region(scene, spec.region)
    return render_frame(scene, spec.frame, spec.output)


def save_pixels(scene, rgba, path: str) -> None:
    """Write an (H, W, 4) float image (row 0 at the bottom) in the scene's output format,
    through Blender's colour management, atomically."""
    import bpy

    height, width = rgba.shape[:2]
    image = bpy.data.images.new("RESTframe pixels", width, height, alpha=True, float_buffer=True)
    try:
        image.pixels.foreach_set(rgba.ravel())
        write_atomically(path, lambda partial: _save_render(image, scene, partial))
    finally:
        bpy.data.images.remove(image)


def _save_render(image, scene, path: str) -> None:
    try:
        image.save_render(filepath=path, scene=scene)
    except RuntimeError as error:
        raise CommandError(f"cannot save the image: {_blender_message(error)}") from None

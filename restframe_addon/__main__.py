"""Headless rendering with Blender as a Python module (``pip install bpy``).

    python -m restframe_addon render FILE.blend -o OUT.png [--frame N | --frames A-B]
    python -m restframe_addon render FILE.blend -o OUT_####.exr --frames A-B --scheduler tcp://HOST:8786
    python -m restframe_addon render FILE.blend -o OUT.exr --frame N --regions 16 --workers 2

The .blend is opened read-only in spirit: settings are changed in memory for the
render (engine, output format) and the file is never saved.  Each frame depends
only on its own time, so frame ranges can be split across machines freely.
The output format follows OUT's extension (``.exr`` = multilayer EXR with every
pass); with no extension the scene's own output settings are used.

With --scheduler (a Dask scheduler), --workers (a Dask LocalCluster of that many
processes on this machine) or --regions (a still split into render-border regions),
frames and regions are rendered by Dask workers (restframe_addon/distributed.py); a
rerun then skips frames already on disk unless --overwrite is given.
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

# extension -> (file format, multilayer)
FORMATS = {
    ".png": ("PNG", False),
    ".jpg": ("JPEG", False),
    ".jpeg": ("JPEG", False),
    ".tif": ("TIFF", False),
    ".tiff": ("TIFF", False),
    ".exr": ("OPEN_EXR_MULTILAYER", True),
}


class CommandError(Exception):
    """A problem with the command line or the file, reported without a traceback."""


def parse_frames(spec: str) -> list[int]:
    """'5' -> [5]; '1-4' -> [1, 2, 3, 4]; '1-9:4' -> [1, 5, 9]; comma-separated lists combine."""
    frames: list[int] = []
    for part in spec.split(","):
        match = re.fullmatch(r"\s*(-?\d+)\s*(?:(?:-|\.\.)\s*(-?\d+)\s*(?::\s*(\d+)\s*)?)?", part)
        if not match:
            raise CommandError(f"bad frame range {part!r}: use N, A-B or A-B:STEP")
        first = int(match.group(1))
        last = int(match.group(2)) if match.group(2) is not None else first
        step = int(match.group(3) or 1)
        if last < first or step < 1:
            raise CommandError(f"bad frame range {part!r}: the end is before the start or the step is not positive")
        frames.extend(range(first, last + 1, step))
    return list(dict.fromkeys(frames))


def output_path(out: str, frame: int, several: bool) -> str:
    """Where one frame goes: '#' runs become the zero-padded frame number (as in Blender);
    without '#', several frames get '_NNNN' before the extension."""
    head, tail = os.path.split(out)
    runs = list(re.finditer(r"#+", tail))
    if runs:
        run = runs[-1]
        tail = tail[:run.start()] + f"{frame:0{len(run.group())}d}" + tail[run.end():]
    elif several:
        stem, ext = os.path.splitext(tail)
        tail = f"{stem}_{frame:04d}{ext}"
    return os.path.join(head, tail)


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
        settings.color_depth = '32'  # full float: pass values (Doppler, times) are quotable
    else:
        settings.color_mode = 'RGBA' if scene.render.film_transparent and file_format != "JPEG" else 'RGB'
    return ext


def open_blend(path: str, scene_name: str | None = None):
    """Load FILE.blend with the add-on registered and RESTframe as its engine."""
    import bpy

    if not os.path.isfile(path):
        raise CommandError(f"{path}: no such .blend file")
    bpy.ops.wm.open_mainfile(filepath=os.path.abspath(path), load_ui=False)
    scene = bpy.data.scenes.get(scene_name) if scene_name else bpy.context.scene
    if scene is None:
        raise CommandError(f"{path}: no scene named {scene_name!r} "
                           f"(scenes: {', '.join(s.name for s in bpy.data.scenes)})")
    scene.render.engine = 'RESTFRAME'
    return scene


def render_frame(scene, frame: int, path: str) -> None:
    """Render one frame and write it to ``path`` atomically (no half-written files)."""
    import bpy

    scene.frame_set(frame)
    try:
        bpy.ops.render.render(write_still=False, scene=scene.name)
    except RuntimeError as error:
        raise CommandError(f"frame {frame}: {str(error).strip()}") from None
    directory = os.path.dirname(os.path.abspath(path))
    os.makedirs(directory, exist_ok=True)
    stem, ext = os.path.splitext(os.path.basename(path))
    partial = os.path.join(directory, f".{stem}.partial-{os.getpid()}{ext}")
    try:
        bpy.data.images["Render Result"].save_render(filepath=partial, scene=scene)
        os.replace(partial, path)
    finally:
        if os.path.exists(partial):
            os.remove(partial)


def parse_region(spec: str) -> tuple[int, int, int, int]:
    """'X0,Y0,X1,Y1' -> pixel rectangle (origin bottom left, X1/Y1 exclusive)."""
    match = re.fullmatch(r"\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*", spec)
    if not match:
        raise CommandError(f"bad region {spec!r}: use X0,Y0,X1,Y1 in pixels (X1 and Y1 exclusive)")
    x0, y0, x1, y1 = map(int, match.groups())
    return x0, y0, x1, y1


def set_region(scene, region: tuple[int, int, int, int]) -> None:
    """Render only this pixel rectangle (Blender's render border, cropped to it)."""
    from .export import full_resolution

    width, height = full_resolution(scene)
    x0, y0, x1, y1 = region
    if not (0 <= x0 < x1 <= width and 0 <= y0 < y1 <= height):
        raise CommandError(f"the region {region} is empty or outside the {width}x{height} image")
    render = scene.render
    render.use_border = True
    render.use_crop_to_border = True

    # fractions a quarter pixel past each edge: truncation (Blender's and the exporter's)
    # gives back the edge exactly despite the single-precision border properties
    def edge(pixels, size):
        return 1.0 if pixels >= size else (pixels + 0.25) / size

    render.border_min_x, render.border_max_x = edge(x0, width), edge(x1, width)
    render.border_min_y, render.border_max_y = edge(y0, height), edge(y1, height)


def blend_assets(blend: str) -> tuple[list[str], list[str]]:
    """Files the open .blend reads (unpacked images): (paths relative to the .blend's folder,
    absolute paths elsewhere)."""
    import bpy

    folder = os.path.dirname(os.path.abspath(blend))
    relative, absolute = [], []
    for image in bpy.data.images:
        if image.packed_file is not None or image.source not in {'FILE', 'SEQUENCE', 'MOVIE', 'TILED'}:
            continue
        if not image.filepath:
            continue
        path = os.path.normpath(bpy.path.abspath(image.filepath, library=image.library))
        inside = os.path.relpath(path, folder)
        if not os.path.exists(path):
            continue  # missing here too: the render warns about it wherever it runs
        if image.filepath.startswith("//") and not inside.startswith(os.pardir) and os.path.isfile(path):
            relative.append(inside)
        else:
            absolute.append(path)
    return sorted(set(relative)), sorted(set(absolute))


def distributed_command(args, scene, out: str, ext: str, frames: list[int]) -> int:
    from . import distributed
    from .export import full_resolution

    if args.region is not None:
        raise CommandError("--region renders one region in this process: it does not combine with the Dask options")
    if args.scheduler is not None and args.workers is not None:
        raise CommandError("--workers starts a local cluster: give it or --scheduler, not both")
    regions = args.regions or 1
    relative, absolute = blend_assets(args.blend)
    job = distributed.Job(
        blend=os.path.abspath(args.blend), scene=scene.name, output_ext=ext,
        frames={frame: output_path(out, frame, len(frames) > 1) for frame in frames},
        samples=args.samples, percentage=args.percentage, resolution=full_resolution(scene),
        regions=regions, assets=relative, missing_assets=absolute,
        scene_format=not os.path.splitext(args.output)[1])

    def write_image(rgba, path):
        """An assembled still in a non-EXR format, through Blender's colour management."""
        import bpy

        height, width = rgba.shape[:2]
        image = bpy.data.images.new("RESTframe regions", width, height, alpha=True, float_buffer=True)
        try:
            image.pixels.foreach_set(rgba.ravel())
            directory = os.path.dirname(os.path.abspath(path))
            os.makedirs(directory, exist_ok=True)
            stem, suffix = os.path.splitext(os.path.basename(path))
            partial = os.path.join(directory, f".{stem}.partial-{os.getpid()}{suffix}")
            try:
                image.save_render(filepath=partial, scene=scene)
                os.replace(partial, path)
            finally:
                if os.path.exists(partial):
                    os.remove(partial)
        finally:
            bpy.data.images.remove(image)

    try:
        failed = distributed.run_job(job, scheduler=args.scheduler, workers=args.workers, retries=args.retries,
                                     overwrite=args.overwrite, write_image=write_image)
    except distributed.DistributedError as error:
        raise CommandError(str(error)) from None
    if failed:
        raise CommandError(f"{failed} frame(s) failed (see above); rerun to render only the missing ones")
    return 0


def render_command(args) -> int:
    import bpy

    import restframe_addon

    if args.frame is not None and args.frames is not None:
        raise CommandError("give either --frame or --frames, not both")
    use_dask = args.scheduler is not None or args.workers is not None or (args.regions or 1) > 1
    if not hasattr(bpy.types.Scene, "restframe"):
        restframe_addon.register()
    scene = open_blend(args.blend, args.scene)
    if scene.render.use_multiview:  # Blender's save_render cannot write a multi-view result from here
        raise CommandError(f"{args.blend}: Stereoscopy (multi-view) is on: the command line cannot write multi-view "
                           "images yet; render with blender -b FILE -E RESTFRAME -f FRAME (every view), or switch "
                           "Stereoscopy off")
    if args.samples is not None:
        scene.restframe.samples = args.samples
    if args.percentage is not None:
        scene.render.resolution_percentage = args.percentage
    ext = configure_output(scene, args.output)
    out = args.output if os.path.splitext(args.output)[1] else args.output + ext
    if args.frames is not None:
        frames = parse_frames(args.frames)
    else:
        frames = [args.frame if args.frame is not None else scene.frame_current]
    if use_dask:
        return distributed_command(args, scene, out, ext, frames)
    if args.region is not None:
        set_region(scene, parse_region(args.region))
    for frame in frames:
        started = time.monotonic()
        path = output_path(out, frame, len(frames) > 1)
        render_frame(scene, frame, path)
        print(f"restframe: frame {frame} -> {path} ({time.monotonic() - started:.2f} s)", flush=True)
    return 0


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="python -m restframe_addon",
                                     description="RESTframe: relativistic rendering of .blend files")
    commands = parser.add_subparsers(dest="command", required=True)
    render = commands.add_parser("render", help="render frames of a .blend file with RESTframe",
                                 description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    render.add_argument("blend", help="the .blend file (never modified)")
    render.add_argument("-o", "--output", required=True,
                        help="output image; '#' runs become the frame number, the extension picks the "
                        "format (.png .jpg .tif, .exr = multilayer EXR with all passes)")
    render.add_argument("--frame", type=int, help="the frame to render (default: the file's current frame)")
    render.add_argument("--frames", help="frames to render: A-B, A-B:STEP or a comma-separated list")
    render.add_argument("--scene", help="scene name (default: the file's active scene)")
    render.add_argument("--samples", type=int, help="override the scene's RESTframe samples")
    render.add_argument("--percentage", type=int, help="override the resolution percentage")
    render.add_argument("--region", metavar="X0,Y0,X1,Y1",
                        help="render only this pixel rectangle (origin bottom left, X1/Y1 exclusive) as a "
                        "cropped image: Blender's render border")
    dask = render.add_argument_group("Dask (render on a cluster; needs dask[distributed])")
    dask.add_argument("--scheduler", metavar="ADDRESS",
                      help="Dask scheduler to send frames to, e.g. tcp://farm:8786")
    dask.add_argument("--workers", type=int, metavar="N",
                      help="without --scheduler: start a Dask LocalCluster of N worker processes here "
                      "(default with --regions: one per CPU)")
    dask.add_argument("--regions", type=int, metavar="N",
                      help="split each frame into N regions rendered by different workers and assembled "
                      "into one image identical to a whole render")
    dask.add_argument("--retries", type=int, default=2, metavar="N",
                      help="times Dask retries a task whose render crashed (default 2); a task whose "
                      "worker dies is rescheduled by the scheduler (distributed.scheduler.allowed-failures, 3 "
                      "by default)")
    dask.add_argument("--overwrite", action="store_true",
                      help="render frames whose output already exists (default: skip them)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        return render_command(args)
    except CommandError as error:
        print(f"restframe: error: {error}", file=sys.stderr)
        return 1


if __name__ == "__main__":
    status = main()
    if "bpy" in sys.modules and sys.modules["bpy"].app.version < (4, 3, 0):
        # bpy 4.2 as a module segfaults in its exit handlers once an add-on registered a property
        # with a getter: leave with the status instead (outputs are already written and closed)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)

"""Headless rendering with Blender as a Python module (``pip install bpy``).

    python -m restframe_addon render FILE.blend -o OUT.png [--frame N | --frames A-B]
    python -m restframe_addon render FILE.blend -o OUT_####.exr --frames A-B --scheduler tcp://HOST:8786
    python -m restframe_addon render FILE.blend -o OUT.exr --frame N --regions 16 --workers 2

The .blend is opened read-only in spirit: settings are changed in memory for the
render (engine, output format, Persistent Data) and the file is never saved.  Each frame depends
only on its own time, so frame ranges can be split across machines freely.
The output format follows OUT's extension (``.exr`` = multilayer EXR with every
pass); with no extension the scene's own output settings are used.

With --scheduler (a Dask scheduler), --workers (a Dask LocalCluster of that many
processes on this machine) or --regions (a still split into render-border regions),
frames and regions are rendered by Dask workers (restframe_addon/distributed.py); a
rerun then skips frames already on disk unless --overwrite is given.

Ctrl-C (SIGINT) or SIGTERM stops the command at once: the frame being rendered is not
written (frames finished before it are complete on disk) and the exit status is 130
(SIGINT) or 143 (SIGTERM).
"""

from __future__ import annotations

import argparse
import os
import re
import sys
import time

from . import headless
from .core.validation import MAX_CAMERA_SAMPLES
from .headless import CommandError, Interrupted

MAX_PERCENTAGE = 32767  # Blender's limit of the resolution percentage

# Blender's frame limits (MINAFRAME, MAXFRAME): scene.frame_set clamps anything beyond them,
# which would render frame 1048574 under another frame's name
FRAME_LIMIT = 1048574


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
        check_frame(first)
        check_frame(last)
        frames.extend(range(first, last + 1, step))
    return list(dict.fromkeys(frames))


def check_frame(frame: int) -> None:
    if abs(frame) > FRAME_LIMIT:
        raise CommandError(f"frame {frame} is beyond Blender's limit of {FRAME_LIMIT} (and -{FRAME_LIMIT})")


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


def parse_region(spec: str) -> tuple[int, int, int, int]:
    """'X0,Y0,X1,Y1' -> pixel rectangle (origin bottom left, X1/Y1 exclusive)."""
    match = re.fullmatch(r"\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*,\s*(\d+)\s*", spec)
    if not match:
        raise CommandError(f"bad region {spec!r}: use X0,Y0,X1,Y1 in pixels (X1 and Y1 exclusive)")
    x0, y0, x1, y1 = map(int, match.groups())
    return x0, y0, x1, y1


def distributed_command(args, scene, out: str, ext: str, frames: list[int]) -> int:
    from . import distributed
    from .export import ExportError, full_resolution
    from .export.settings import border_region

    if args.region is not None:
        raise CommandError("--region renders one region in this process: it does not combine with the Dask options")
    if args.scheduler is not None and args.workers is not None:
        raise CommandError("--workers starts a local cluster: give it or --scheduler, not both")
    if (args.regions or 1) > 1:
        headless.check_exr_pixel_aspect(scene, "--regions (each region travels as a multilayer EXR): ",
                                        instead="render the frame whole")
    relative, absolute = distributed.blend_assets(args.blend)
    try:
        border = border_region(scene, full_resolution(scene))
    except ExportError as error:
        raise CommandError(str(error)) from None
    job = distributed.Job(
        blend=os.path.abspath(args.blend), scene=scene.name, output_ext=ext,
        frames={frame: output_path(out, frame, len(frames) > 1) for frame in frames},
        samples=args.samples, percentage=args.percentage, resolution=full_resolution(scene),
        regions=args.regions or 1, border=border, crop=scene.render.use_crop_to_border,
        assets=relative, missing_assets=absolute,
        scene_format=not os.path.splitext(args.output)[1])
    headless.check_writable(job.frames.values())
    try:
        failed = distributed.run_job(job, scheduler=args.scheduler, workers=args.workers, retries=args.retries,
                                     overwrite=args.overwrite,
                                     write_image=lambda rgba, path: headless.save_pixels(scene, rgba, path))
    except distributed.DistributedError as error:
        raise CommandError(str(error)) from None
    if failed:
        raise CommandError(f"{failed} frame(s) failed (see above); rerun to render only the missing ones")
    return 0


def render_command(args) -> int:
    if args.frame is not None and args.frames is not None:
        raise CommandError("give either --frame or --frames, not both")
    if args.frame is not None:
        check_frame(args.frame)
    frames = parse_frames(args.frames) if args.frames is not None else None
    region = parse_region(args.region) if args.region is not None else None
    use_dask = args.scheduler is not None or args.workers is not None or (args.regions or 1) > 1
    scene = headless.open_blend(args.blend, args.scene)
    if scene.render.use_multiview:  # Blender's save_render cannot write a multi-view result from here
        raise CommandError(f"{args.blend}: Stereoscopy (multi-view) is on: the command line cannot write multi-view "
                           "images yet; render with blender -b FILE -E RESTFRAME -f FRAME (every view), or switch "
                           "Stereoscopy off")
    headless.apply_overrides(scene, args.samples, args.percentage)
    if args.denoise:
        if use_dask:
            raise CommandError("--denoise works on whole frames rendered here, not with Dask")
        from .denoise import use_denoiser

        use_denoiser(scene)
    ext = headless.configure_output(scene, args.output)
    out = args.output if os.path.splitext(args.output)[1] else args.output + ext
    if frames is None:
        frames = [args.frame if args.frame is not None else scene.frame_current]
    if use_dask:
        return distributed_command(args, scene, out, ext, frames)
    if region is not None:
        headless.set_region(scene, region)
    paths = {frame: output_path(out, frame, len(frames) > 1) for frame in frames}
    headless.check_writable(paths.values())
    # Blender's Persistent Data, in memory only: the engine is kept from frame to frame and
    # traces unchanged rest-frame geometry without building it again (the same pixels)
    scene.render.use_persistent_data = not args.no_persistent_data
    for frame, path in paths.items():
        started = time.monotonic()
        headless.render_frame(scene, frame, path)
        print(f"restframe: frame {frame} -> {path} ({time.monotonic() - started:.2f} s)", flush=True)
    return 0


def at_least(minimum: int, at_most: int | None = None):
    """An argparse type: an integer no smaller than ``minimum`` (and no larger than ``at_most``:
    Blender would clamp a larger value without a word)."""

    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"not a whole number: {text!r}") from None
        if value < minimum:
            raise argparse.ArgumentTypeError(f"must be at least {minimum} (got {value})")
        if at_most is not None and value > at_most:
            raise argparse.ArgumentTypeError(f"must be at most {at_most} (got {value})")
        return value

    parse.__name__ = f"integer >= {minimum}" if at_most is None else f"integer {minimum}..{at_most}"
    return parse


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
    render.add_argument("--samples", type=at_least(1, MAX_CAMERA_SAMPLES),
                        help="override the scene's RESTframe samples")
    render.add_argument("--percentage", type=at_least(1, MAX_PERCENTAGE), help="override the resolution percentage")
    render.add_argument("--region", metavar="X0,Y0,X1,Y1",
                        help="render only this pixel rectangle (origin bottom left, X1/Y1 exclusive) as a "
                        "cropped image: Blender's render border")
    render.add_argument("--no-persistent-data", action="store_true",
                        help="build every frame's rest frames afresh (default: the frames of one command reuse "
                        "the geometry of bodies unchanged in their rest frames, as with Blender's Persistent Data)")
    render.add_argument("--denoise", action="store_true",
                        help="denoise with Blender's Denoise node (OpenImageDenoise) from the Denoising "
                        "Albedo and Normal passes; replaces the file's compositing set-up for this render")
    dask = render.add_argument_group("Dask (render on a cluster; needs dask[distributed])")
    dask.add_argument("--scheduler", metavar="ADDRESS",
                      help="Dask scheduler to send frames to, e.g. tcp://farm:8786")
    dask.add_argument("--workers", type=at_least(1), metavar="N",
                      help="without --scheduler: start a Dask LocalCluster of N worker processes here "
                      "(default with --regions: one per CPU)")
    dask.add_argument("--regions", type=at_least(1), metavar="N",
                      help="split each frame into N regions rendered by different workers and assembled "
                      "into one image identical to a whole render")
    dask.add_argument("--retries", type=at_least(0), default=2, metavar="N",
                      help="times Dask retries a task whose render crashed (default 2); a task whose "
                      "worker dies is rescheduled by the scheduler (distributed.scheduler.allowed-failures, 3 "
                      "by default)")
    dask.add_argument("--overwrite", action="store_true",
                      help="render frames whose output already exists (default: skip them)")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    try:
        with headless.interruptible():
            return render_command(args)
    except CommandError as error:
        print(f"restframe: error: {error}", file=sys.stderr)
        return 1
    except Interrupted as interrupt:
        print(f"restframe: {interrupt}", file=sys.stderr, flush=True)
        return interrupt.status


if __name__ == "__main__":
    status = main()
    if "bpy" in sys.modules and sys.modules["bpy"].app.version < (4, 3, 0):
        # bpy 4.2 as a module segfaults in its exit handlers once an add-on registered a property
        # with a getter: leave with the status instead (outputs are already written and closed)
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(status)
    sys.exit(status)

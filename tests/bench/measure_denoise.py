"""Blender's Denoise node (OpenImageDenoise) on low-sample renders: RMSE to a high-sample reference.

    tools/dev.sh tests/bench/measure_denoise.py [--size 64] [--samples 16] [--reference 1024]
        [--scenes cornell,default,hdri] [--engines RESTFRAME,CYCLES] [--json OUT]

For each scene (the Cornell box, Blender's default startup scene and the glossy/metal HDRI scene of
tests/blender/test_blender_path.py) and each engine, the raw SAMPLES render and the same render
through the compositor's Denoise node (with the engine's Denoising Albedo and Normal passes, each
Prefilter setting; and with the image alone) are compared with the engine's own REFERENCE render:
gain = RMSE(raw) / RMSE(denoised).  Cycles beside RESTframe tells what the passes are worth.
Section 7 of the benchmark suite runs it (``--json``: the rows for the report).
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[2]
sys.path[:0] = [str(ROOT), str(ROOT / "tests" / "blender")]

VARIANTS = (("image, albedo, normal; prefilter Accurate", "Accurate", True),
            ("image, albedo, normal; prefilter Fast", "Fast", True),
            ("image, albedo, normal; prefilter None", "None", True),
            ("image only", "Accurate", False))


def scene_named(name):
    import test_blender_path as path_tests

    return {"cornell": path_tests.cornell_box, "default": path_tests.default_scene,
            "hdri": path_tests.hdri_scene}[name]()


def set_up(scene, engine, size, bounces=4):
    """Both engines as the Cycles comparison tests set them (box pixels, same bounce limits)."""
    import test_blender_path as path_tests

    path_tests.SIZE = size
    path_tests.render_pair(scene, Path(tempfile.mkdtemp()), samples=1, bounces=bounces, seeds=(1,))
    scene.render.engine = engine
    scene.view_layers[0].cycles.denoising_store_passes = engine == 'CYCLES'


def set_samples(scene, engine, samples, seed):
    if engine == 'CYCLES':
        scene.cycles.samples, scene.cycles.seed = samples, seed
    else:
        scene.restframe.samples = samples


def denoise_node(scene):
    tree = scene.compositing_node_group if hasattr(scene, "compositing_node_group") else scene.node_tree
    return tree, next(n for n in tree.nodes if n.bl_idname == "CompositorNodeDenoise")


def measure(name, engine, size, samples, reference_samples, folder):
    from blender_helpers import render_rgba

    from restframe_addon.denoise import use_denoiser

    scene = scene_named(name)
    set_up(scene, engine, size)
    set_samples(scene, engine, reference_samples, 7)
    started = time.perf_counter()
    reference = render_rgba(scene, folder / f"{name}_{engine}_ref.exr")[..., :3]
    reference_seconds = time.perf_counter() - started
    set_samples(scene, engine, samples, 3)
    raw = render_rgba(scene, folder / f"{name}_{engine}_raw.exr")[..., :3]
    use_denoiser(scene)
    if engine == 'CYCLES':
        scene.view_layers[0].cycles.denoising_store_passes = True
    tree, node = denoise_node(scene)
    rmse = lambda image: float(np.sqrt(np.mean((image - reference) ** 2)))  # noqa: E731
    rows = [("raw", rmse(raw), 1.0)]
    for label, prefilter, auxiliary in VARIANTS:
        if "Prefilter" in node.inputs:  # a menu socket from Blender 5.0, a property before
            node.inputs["Prefilter"].default_value = prefilter
        else:
            node.prefilter = prefilter.upper()
        if not auxiliary:
            for socket in ("Albedo", "Normal"):
                for link in list(node.inputs[socket].links):
                    tree.links.remove(link)
        denoised = render_rgba(scene, folder / f"{name}_{engine}_{prefilter}{auxiliary}.exr")[..., :3]
        rows.append((label, rmse(denoised), rmse(raw) / rmse(denoised)))
    return rows, reference_seconds, float(reference.mean())


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--size", type=int, default=64)
    parser.add_argument("--samples", type=int, default=16)
    parser.add_argument("--reference", type=int, default=1024)
    parser.add_argument("--scenes", default="cornell,default,hdri")
    parser.add_argument("--engines", default="RESTFRAME,CYCLES")
    parser.add_argument("--json", help="also write the rows here")
    args = parser.parse_args()
    import bpy

    import restframe_addon

    restframe_addon.register()
    folder = Path(tempfile.mkdtemp())
    print(f"{args.size}x{args.size} px, {args.samples} samples against {args.reference}; Blender {bpy.app.version_string}")
    print("| scene | engine | render | RMSE to reference | gain |")
    print("| --- | --- | --- | --- | --- |")
    table = []
    for name in args.scenes.split(","):
        for engine in args.engines.split(","):
            rows, seconds, mean = measure(name, engine, args.size, args.samples, args.reference, folder)
            for label, error, gain in rows:
                print(f"| {name} | {engine} | {label} | {error:.4g} | {gain:.2f} |", flush=True)
                table.append(dict(scene=name, engine=engine, render=label, error=error, gain=gain))
            print(f"({name}, {engine}: reference {seconds:.0f} s, mean {mean:.3g})", file=sys.stderr, flush=True)
    if args.json:
        Path(args.json).write_text(json.dumps(table))


if __name__ == "__main__":
    main()

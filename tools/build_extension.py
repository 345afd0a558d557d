"""Build RESTframe's installable Blender extension: one zip per platform, each with its embreex wheels.

    tools/dev.sh tools/build_extension.py    # -> dist/restframe-<version>-linux_x64.zip
                                             #    dist/restframe-<version>-windows_x64.zip

embreex (the ray-query library the tracer needs) is not part of Blender, so each zip carries
its wheels for CPython 3.11 (Blender 4.2-5.0) and 3.13 (later releases), for that zip's
platform only.  The id, version and platforms are the manifest's (blender_manifest.toml, the
one place they are written).  The committed manifest lists no wheels (they are not in git):
this script stages a copy of the add-on with every platform's wheels and a manifest naming
them, and Blender's own ``blender_ext.py build --split-platforms`` writes one zip per
platform, leaving out the other platforms' wheels (``[build.generated]`` in each zip's
manifest names its platform and wheels), then ``validate`` checks each zip.
"""

from __future__ import annotations

import argparse
import fnmatch
import glob
import importlib.metadata
import importlib.util
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
MANIFEST = os.path.join(ROOT, "blender_manifest.toml")
# Blender platform -> (pip --platform, wheel file platform pattern) of embreex's wheels
WHEEL_PLATFORMS = {
    "linux-x64": ("manylinux_2_28_x86_64", "*manylinux*x86_64"),
    "windows-x64": ("win_amd64", "win_amd64"),
}
PYTHONS = ("3.11", "3.13")


def read_manifest() -> tuple[str, dict]:
    """The committed manifest's text and its parsed table."""
    with open(MANIFEST, encoding="utf-8") as fh:
        text = fh.read()
    return text, tomllib.loads(text)


def zip_name(manifest: dict, platform: str) -> str:
    """The file name ``blender_ext.py build --split-platforms`` gives a platform's zip."""
    return f"{manifest['id']}-{manifest['version']}-{platform.replace('-', '_')}.zip"


def blender_ext_script() -> str:
    """Blender's extension tool, shipped inside the bpy module's scripts."""
    spec = importlib.util.find_spec("bpy")
    if spec is None or not spec.submodule_search_locations:
        raise SystemExit("bpy is not installed here: run this with tools/dev.sh, or pass --blender-ext")
    base = list(spec.submodule_search_locations)[0]
    found = sorted(glob.glob(os.path.join(base, "*", "scripts", "addons_core", "bl_pkg", "cli", "blender_ext.py")))
    if not found:
        raise SystemExit(f"blender_ext.py not found under {base}")
    return found[-1]


def blender_tags(script: str) -> str:
    """Blender's list of valid tags, which ``blender --command extension build/validate`` checks
    against (``blender_ext.py`` run on its own does not, unless given it)."""
    return os.path.normpath(os.path.join(os.path.dirname(script), os.pardir, os.pardir, os.pardir,
                                         "modules", "_bpy_internal", "extensions", "tags.py"))


def validate_command(script: str, path: str) -> list[str]:
    """``blender_ext.py validate`` of a built zip (or source folder), tags checked as Blender does."""
    return [sys.executable, script, "validate", "--valid-tags", blender_tags(script), path]


def download_wheels(version: str, cache: str, platforms: list[str]) -> list[str]:
    """embreex wheels for every platform and Python, cached between builds."""
    unknown = sorted(set(platforms) - set(WHEEL_PLATFORMS))
    if unknown:
        raise SystemExit(f"no embreex wheels known for the manifest's platforms {unknown}")
    os.makedirs(cache, exist_ok=True)
    wheels = []
    for platform in platforms:
        pip_platform, file_platform = WHEEL_PLATFORMS[platform]
        for python in PYTHONS:
            tag = "cp" + python.replace(".", "")
            pattern = os.path.join(cache, f"embreex-{version}-{tag}-{tag}-{file_platform}.whl")
            if not glob.glob(pattern):
                subprocess.run(
                    [sys.executable, "-m", "pip", "download", "--quiet", "--disable-pip-version-check",
                     "--only-binary=:all:", "--no-deps", "--platform", pip_platform,
                     "--python-version", python, "--implementation", "cp",
                     "--dest", cache, f"embreex=={version}"],
                    check=True,
                )
            found = sorted(glob.glob(pattern))
            if not found:
                raise SystemExit(f"pip found no embreex {version} wheel for {tag} {pip_platform}")
            wheels.append(found[-1])
    return wheels


def staged_manifest(text: str, wheel_names: list[str]) -> str:
    """The committed manifest plus the bundled wheels (a top-level key, before the first table)."""
    wheels = "".join(f'  "./wheels/{name}",\n' for name in wheel_names)
    lines = text.splitlines(keepends=True)
    first_table = next(i for i, line in enumerate(lines) if line.lstrip().startswith("["))
    return "".join(lines[:first_table]) + f"wheels = [\n{wheels}]\n\n" + "".join(lines[first_table:])


def stage_ignore(exclude_patterns: list[str]):
    """``shutil.copytree`` filter leaving out what the manifest's ``paths_exclude_pattern`` leaves
    out of the zip anyway (``/name`` at the root, other patterns anywhere), and any old ``wheels``."""
    at_root = [pattern.strip("/") for pattern in exclude_patterns if pattern.startswith("/")] + ["wheels"]
    anywhere = [pattern.rstrip("/") for pattern in exclude_patterns if not pattern.startswith("/")]

    def ignore(directory, names):
        patterns = anywhere + (at_root if os.path.samefile(directory, ROOT) else [])
        return {name for name in names if any(fnmatch.fnmatch(name, pattern) for pattern in patterns)}

    return ignore


def build(output_dir: str | None = None, embreex_version: str | None = None,
          wheel_cache: str | None = None, blender_ext: str | None = None) -> dict[str, str]:
    """Build and validate every platform's zip; {Blender platform: zip path}."""
    text, manifest = read_manifest()
    platforms = manifest["platforms"]
    version = embreex_version or importlib.metadata.version("embreex")
    cache = wheel_cache or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "restframe", "wheels")
    wheels = download_wheels(version, cache, platforms)

    output_dir = os.path.abspath(output_dir or os.path.join(ROOT, "dist"))
    os.makedirs(output_dir, exist_ok=True)
    zips = {platform: os.path.join(output_dir, zip_name(manifest, platform)) for platform in platforms}
    script = blender_ext or blender_ext_script()
    with tempfile.TemporaryDirectory(prefix="restframe-extension-") as temp:
        stage = os.path.join(temp, manifest["id"])
        shutil.copytree(ROOT, stage, ignore=stage_ignore(manifest["build"]["paths_exclude_pattern"]))
        os.makedirs(os.path.join(stage, "wheels"))
        for wheel in wheels:
            shutil.copy2(wheel, os.path.join(stage, "wheels"))
        with open(os.path.join(stage, "blender_manifest.toml"), "w", encoding="utf-8") as fh:
            fh.write(staged_manifest(text, [os.path.basename(w) for w in wheels]))
        for path in zips.values():
            if os.path.exists(path):
                os.remove(path)
        subprocess.run([sys.executable, script, "build", "--split-platforms", "--valid-tags", blender_tags(script),
                        "--source-dir", stage, "--output-dir", output_dir], check=True)
    for path in zips.values():
        subprocess.run(validate_command(script, path), check=True)
    return zips


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--output-dir", help="where the zips go (default: dist/)")
    parser.add_argument("--embreex-version", help="embreex version to bundle (default: the installed one)")
    parser.add_argument("--wheel-cache", help="where downloaded wheels are kept (default: ~/.cache/restframe/wheels)")
    parser.add_argument("--blender-ext", help="path of Blender's blender_ext.py (default: the one in bpy)")
    args = parser.parse_args(argv)
    for platform, path in build(args.output_dir, args.embreex_version, args.wheel_cache, args.blender_ext).items():
        print(f"built {path} ({platform}, {os.path.getsize(path) / 1e6:.1f} MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Build RESTframe's installable Blender extension zip, with embreex wheels bundled.

    tools/dev.sh tools/build_extension.py            # -> dist/restframe-<version>.zip

embreex (the ray-query library the tracer needs) is not part of Blender, so the
zip carries its wheels: Linux x86_64 and Windows x64, for CPython 3.11 (Blender
4.2-5.0) and 3.13 (later releases).  embreex publishes no macOS wheels, so there
is no macOS build.  The committed manifest lists no wheels (they are not in git);
this script stages a copy of the add-on in build/extension with the wheels and a
manifest naming them, and lets Blender's own ``blender_ext.py build`` validate
the manifest and write the zip (honouring ``[build] paths_exclude_pattern``).
"""

from __future__ import annotations

import argparse
import glob
import importlib.metadata
import importlib.util
import os
import shutil
import subprocess
import sys

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
# (pip --platform, wheel file platform pattern, Blender platform)
PLATFORMS = (
    ("manylinux_2_28_x86_64", "*manylinux*x86_64", "linux-x64"),
    ("win_amd64", "win_amd64", "windows-x64"),
)
PYTHONS = ("3.11", "3.13")
STAGE_IGNORE = (".git", ".ci", ".pytest_cache", "__pycache__", "build", "dist", "out", "tests",
                "sample_blends", "tools", "docs", "wheels")


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


def download_wheels(version: str, cache: str) -> list[str]:
    """embreex wheels for every supported platform and Python, cached between builds."""
    os.makedirs(cache, exist_ok=True)
    wheels = []
    for pip_platform, file_platform, _ in PLATFORMS:
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
    """The committed manifest plus the platforms and the bundled wheels (top-level keys)."""
    platforms = ", ".join(f'"{p[2]}"' for p in PLATFORMS)
    wheels = "".join(f'  "./wheels/{name}",\n' for name in wheel_names)
    extra = f"platforms = [{platforms}]\nwheels = [\n{wheels}]\n\n"
    lines = text.splitlines(keepends=True)
    first_table = next(i for i, line in enumerate(lines) if line.lstrip().startswith("["))
    return "".join(lines[:first_table]) + extra + "".join(lines[first_table:])


def manifest_value(text: str, key: str) -> str:
    import tomllib

    return tomllib.loads(text)[key]


def build(output: str | None = None, embreex_version: str | None = None,
          wheel_cache: str | None = None, blender_ext: str | None = None) -> str:
    version = embreex_version or importlib.metadata.version("embreex")
    cache = wheel_cache or os.path.join(
        os.environ.get("XDG_CACHE_HOME", os.path.expanduser("~/.cache")), "restframe", "wheels")
    wheels = download_wheels(version, cache)

    stage = os.path.join(ROOT, "build", "extension")
    shutil.rmtree(stage, ignore_errors=True)
    shutil.copytree(ROOT, stage, ignore=shutil.ignore_patterns(*STAGE_IGNORE, "*.pyc", "*.blend1", "*.zip"))
    os.makedirs(os.path.join(stage, "wheels"))
    for wheel in wheels:
        shutil.copy2(wheel, os.path.join(stage, "wheels"))
    with open(os.path.join(ROOT, "blender_manifest.toml"), encoding="utf-8") as fh:
        manifest = fh.read()
    with open(os.path.join(stage, "blender_manifest.toml"), "w", encoding="utf-8") as fh:
        fh.write(staged_manifest(manifest, [os.path.basename(w) for w in wheels]))

    output = os.path.abspath(output or os.path.join(
        ROOT, "dist", f"{manifest_value(manifest, 'id')}-{manifest_value(manifest, 'version')}.zip"))
    os.makedirs(os.path.dirname(output), exist_ok=True)
    if os.path.exists(output):
        os.remove(output)
    script = blender_ext or blender_ext_script()
    subprocess.run([sys.executable, script, "build", "--source-dir", stage, "--output-filepath", output], check=True)
    subprocess.run([sys.executable, script, "validate", output], check=True)
    return output


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("-o", "--output", help="zip to write (default: dist/<id>-<version>.zip)")
    parser.add_argument("--embreex-version", help="embreex version to bundle (default: the installed one)")
    parser.add_argument("--wheel-cache", help="where downloaded wheels are kept (default: ~/.cache/restframe/wheels)")
    parser.add_argument("--blender-ext", help="path of Blender's blender_ext.py (default: the one in bpy)")
    args = parser.parse_args(argv)
    path = build(args.output, args.embreex_version, args.wheel_cache, args.blender_ext)
    print(f"built {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())

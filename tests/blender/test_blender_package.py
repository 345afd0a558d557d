"""The installable extension: manifest valid, one zip per platform with its own wheels, each
validated by Blender's tool, the Linux one installed and rendering; the README and the changelog
name the manifest's version."""

import glob
import json
import os
import re
import subprocess
import sys
import tomllib
import zipfile

import pytest

from blender_helpers import read_exr

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import build_extension  # noqa: E402

MANIFEST = build_extension.read_manifest()[1]
# Blender platform -> the wheel platform tag part that marks its embreex wheels
WHEEL_TAG = {"linux-x64": "manylinux", "windows-x64": "win_amd64"}


def test_committed_manifest_is_valid():
    result = subprocess.run(build_extension.validate_command(build_extension.blender_ext_script(), ROOT),
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert MANIFEST["platforms"] == ["linux-x64", "windows-x64"]


@pytest.fixture(scope="module")
def extension_zips(tmp_path_factory):
    """{platform: zip} built by tools/build_extension.py into a fresh folder."""
    out = tmp_path_factory.mktemp("dist")
    subprocess.run([sys.executable, os.path.join(ROOT, "tools", "build_extension.py"), "--output-dir", str(out)],
                   check=True, cwd=ROOT, capture_output=True, text=True)
    assert sorted(os.listdir(out)) == sorted(build_extension.zip_name(MANIFEST, p) for p in MANIFEST["platforms"])
    return {platform: out / build_extension.zip_name(MANIFEST, platform) for platform in MANIFEST["platforms"]}


@pytest.mark.parametrize("platform", ["linux-x64", "windows-x64"])
def test_zip_has_only_its_platforms_wheels(extension_zips, platform):
    with zipfile.ZipFile(extension_zips[platform]) as archive:
        names = archive.namelist()
        manifest = tomllib.loads(archive.read("blender_manifest.toml").decode())
    assert "__init__.py" in names and "restframe_addon/engine.py" in names and "restframe_addon/core/render.py" in names
    assert "restframe_addon/export/scene.py" in names and "restframe_addon/motion_query.py" in names
    assert not [n for n in names if n.startswith(("tests/", "sample_blends/", "tools/", "docs/", ".ci/", ".git"))]
    wheels = sorted(n for n in names if n.startswith("wheels/"))
    assert len(wheels) == 2
    for python in ("cp311", "cp313"):
        assert any(python in w and WHEEL_TAG[platform] in w for w in wheels)
    assert not [w for w in wheels if WHEEL_TAG[platform] not in w]
    generated = manifest["build"]["generated"]  # what Blender installs from a split zip
    assert generated["platforms"] == [platform]
    assert sorted(w.removeprefix("./") for w in generated["wheels"]) == wheels
    assert manifest["version"] == MANIFEST["version"] and "permissions" not in manifest


@pytest.mark.parametrize("platform", ["linux-x64", "windows-x64"])
def test_zip_passes_blender_validate(extension_zips, platform):
    result = subprocess.run(build_extension.validate_command(build_extension.blender_ext_script(),
                                                             str(extension_zips[platform])),
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr
    assert f'Success parsing TOML in "{extension_zips[platform]}"' in result.stdout


def test_installed_zip_renders(extension_zips, tmp_path):
    user = tmp_path / "user"
    user.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user))
    out = tmp_path / "installed.exr"
    result = subprocess.run([sys.executable, os.path.join(HERE, "install_and_render.py"),
                             str(extension_zips["linux-x64"]), str(out)],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["install"] == ["FINISHED"]
    assert report["module"].startswith(str(user))
    assert report["embreex"].startswith(report["site"]) and report["site"].startswith(str(user))
    # The manifest asks for no permissions because the loaded extension stays out of the
    # command line's modules (output files, worker processes, Dask networking).
    assert report["command_line_modules"] == []
    doppler = read_exr(out)["Doppler"]
    assert doppler[7, 10, 0] == pytest.approx(4.358898943540674, abs=1e-6)
    assert glob.glob(os.path.join(str(user), "extensions", "user_default", "restframe", "restframe_addon", "engine.py"))


def test_readme_and_changelog_name_the_manifest_version():
    """The version is written once, in the manifest; these say which one it is."""
    version = MANIFEST["version"]
    with open(os.path.join(ROOT, "README.md"), encoding="utf-8") as fh:
        readme = fh.read()
    with open(os.path.join(ROOT, "CHANGELOG.md"), encoding="utf-8") as fh:
        changelog = fh.read()
    for platform in MANIFEST["platforms"]:
        assert build_extension.zip_name(MANIFEST, platform) in readme
    assert set(re.findall(r"restframe-(\d+\.\d+\.\d+)", readme)) == {version}
    released = re.findall(r"^## \[(\d+\.\d+\.\d+)\]", changelog, flags=re.M)
    assert released and released[0] == version  # the newest release section is the manifest's version
    assert changelog.index("## [Unreleased]") < changelog.index(f"## [{version}]")

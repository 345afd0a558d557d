"""The installable extension: manifest valid, zip built with wheels, installed and rendering."""

import glob
import json
import os
import subprocess
import sys
import zipfile

import pytest

from blender_helpers import read_exr

ROOT = os.path.dirname(os.path.dirname(os.path.dirname(os.path.abspath(__file__))))
HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.join(ROOT, "tools"))
import build_extension  # noqa: E402


def test_committed_manifest_is_valid():
    result = subprocess.run([sys.executable, build_extension.blender_ext_script(), "validate", ROOT],
                            capture_output=True, text=True)
    assert result.returncode == 0, result.stdout + result.stderr


@pytest.fixture(scope="module")
def extension_zip(tmp_path_factory):
    path = tmp_path_factory.mktemp("dist") / "restframe.zip"
    subprocess.run([sys.executable, os.path.join(ROOT, "tools", "build_extension.py"), "-o", str(path)],
                   check=True, cwd=ROOT, capture_output=True, text=True)
    return path


def test_zip_contents(extension_zip):
    with zipfile.ZipFile(extension_zip) as archive:
        names = archive.namelist()
        manifest = archive.read("blender_manifest.toml").decode()
    assert "__init__.py" in names and "restframe_addon/engine.py" in names and "restframe_addon/core/render.py" in names
    assert "restframe_addon/export/scene.py" in names and "restframe_addon/motion_query.py" in names
    assert not [n for n in names if n.startswith(("tests/", "sample_blends/", "tools/", ".ci/", ".git"))]
    wheels = sorted(n for n in names if n.startswith("wheels/"))
    assert len(wheels) == 4
    for python in ("cp311", "cp313"):
        assert any(python in w and "manylinux" in w and "x86_64" in w for w in wheels)
        assert any(python in w and "win_amd64" in w for w in wheels)
    assert 'platforms = ["linux-x64", "windows-x64"]' in manifest
    assert all(f'"./{w}"' in manifest for w in wheels)


def test_installed_zip_renders(extension_zip, tmp_path):
    user = tmp_path / "user"
    user.mkdir()
    env = dict(os.environ, BLENDER_USER_RESOURCES=str(user))
    out = tmp_path / "installed.exr"
    result = subprocess.run([sys.executable, os.path.join(HERE, "install_and_render.py"), str(extension_zip), str(out)],
                            env=env, cwd=tmp_path, capture_output=True, text=True, timeout=300)
    assert result.returncode == 0, result.stdout + result.stderr
    report = json.loads(result.stdout.strip().splitlines()[-1])
    assert report["install"] == ["FINISHED"]
    assert report["module"].startswith(str(user))
    assert report["embreex"].startswith(report["site"]) and report["site"].startswith(str(user))
    doppler = read_exr(out)["Doppler"]
    assert doppler[7, 10, 0] == pytest.approx(4.358898943540674, abs=1e-6)
    assert glob.glob(os.path.join(str(user), "extensions", "user_default", "restframe", "restframe_addon", "engine.py"))

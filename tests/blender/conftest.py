"""Fixtures for the Blender-layer tests (bpy as a Python module, no Blender binary)."""

import bpy
import pytest

import restframe_addon


@pytest.fixture(scope="session", autouse=True)
def addon():
    """The add-on registered once for the session, as Blender does at startup."""
    restframe_addon.register()
    yield
    restframe_addon.unregister()


@pytest.fixture
def scene(addon):
    """An empty factory scene rendered with RESTframe at a tiny odd resolution."""
    bpy.ops.wm.read_factory_settings(use_empty=True)
    scene = bpy.context.scene
    scene.render.engine = 'RESTFRAME'
    scene.render.resolution_x, scene.render.resolution_y = 21, 15
    scene.render.resolution_percentage = 100
    scene.view_settings.view_transform = 'Standard'  # 5.0 defaults to AgX: keep pixel values plain
    scene.restframe.light_speed = 10.0
    scene.restframe.samples = 1
    scene.restframe.integrator = 'DIRECT'  # these tests are about the direct-light renderer
    return scene


_status = {}


def pytest_sessionfinish(session, exitstatus):
    _status["exit"] = int(exitstatus)


def pytest_unconfigure(config):
    """bpy 4.2 (as a Python module) crashes in its exit handlers once an add-on has registered a
    property with a getter (RESTframe's computed Speed/Gamma/Rapidity): after the report, leave
    with pytest's own status instead of a segfault.  Blender 4.3+ does not need this."""
    if bpy.app.version < (4, 3, 0) and "exit" in _status:
        import os
        import sys
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(_status["exit"])

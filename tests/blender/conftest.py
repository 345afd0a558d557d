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
    return scene

"""Each image is held once: the scene's image is a view into the lookup layout (world.Texels),
which the prepared scene's lookups share, in this process and in a worker's unpickled copy."""

import gc
import pickle

import numpy as np
import pytest
from shapes import look_at_camera, quad

from restframe_addon.core.prepared import prepare
from restframe_addon.core.scene import Material, Mesh, RenderSettings, Scene, WorldTexture
from restframe_addon.core.world import texel_image


def big_buffers(root, at_least: int) -> dict[int, int]:
    """The memory-owning float32 numpy buffers (the images' precision; the sampling tables are
    float64) of at least ``at_least`` bytes reachable from ``root``: {id: bytes}."""
    seen, found, stack = set(), {}, [root]
    while stack:
        item = stack.pop()
        if id(item) in seen or isinstance(item, type) or callable(item) and not hasattr(item, "__dict__"):
            continue
        seen.add(id(item))
        if isinstance(item, np.ndarray):
            owner = item
            while isinstance(owner.base, np.ndarray):
                owner = owner.base
            if owner.dtype == np.float32 and owner.nbytes >= at_least:
                found[id(owner)] = owner.nbytes
            if owner.dtype != object:
                continue
        stack.extend(gc.get_referents(item))
    return found


def textured_scene():
    rng = np.random.default_rng(3)
    texture = texel_image(rng.random((64, 128, 3), dtype=np.float32))
    environment = texel_image(rng.random((128, 256, 3), dtype=np.float32))
    floor = Mesh("floor", *quad(size=(2.0, 2.0)))
    material = Material("textured", base_color_texture=texture, normal_texture=texture)
    scene = Scene(camera=look_at_camera((0, -3, 2), (0, 0, 0)), meshes=[floor], materials=[material],
                  world_texture=WorldTexture(environment, strength=2.0))
    return scene, (texture, environment)


@pytest.mark.parametrize("integrator", ["DIRECT", "PATH"])
def test_the_prepared_scene_and_its_pickled_copy_hold_each_image_once(integrator):
    scene, images = textured_scene()
    layouts = {id(image.base): image.base.nbytes for image in images}
    settings = RenderSettings(resolution=(4, 4), samples=1, integrator=integrator)
    prepared = prepare(scene, settings)
    smallest = min(layouts.values()) // 2
    assert big_buffers(prepared, smallest) == layouts
    worker = pickle.loads(pickle.dumps(prepared, protocol=pickle.HIGHEST_PROTOCOL))  # as core.workers pickles it
    held = big_buffers(worker, smallest)
    assert sorted(held.values()) == sorted(layouts.values())


def test_a_texel_image_is_its_image_and_pickles_as_one():
    image = np.random.default_rng(4).random((5, 7, 3), dtype=np.float32)
    view = texel_image(image)
    assert np.array_equal(view, image) and not view.flags.writeable
    material = pickle.loads(pickle.dumps(Material("m", base_color_texture=view)))
    assert np.array_equal(material.base_color_texture, image)
    assert texel_image(material.base_color_texture).base is material.base_color_texture.base  # no new layout

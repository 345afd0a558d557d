"""Fuzz: random scenes at tiny resolution never crash and keep the physical invariants (issue 9).

Seeded and of a fixed size: ``CASES`` scenes, scene i from ``SEED + i`` (named in the failure), so a
run checks the same scenes on any machine, however fast.  RESTFRAME_FUZZ_CASES and RESTFRAME_FUZZ_SEED
change both for longer hunts.
"""

import os

import numpy as np

from restframe_addon.core.motion import Trajectory
from restframe_addon.core.render import render_image
from restframe_addon.core.scene import Light, Material, Mesh, RenderSettings, Scene, Velocity
from shapes import box, look_at_camera, quad, uv_sphere

SEED = int(os.environ.get("RESTFRAME_FUZZ_SEED", "20261123"))
CASES = int(os.environ.get("RESTFRAME_FUZZ_CASES", "100"))
MISS_DEPTH = 1e10  # the Depth pass where a ray hits nothing


def random_velocity(rng, fast=True):
    """Up to 1 - 1e-9 c: near c through the Lorentz factor, as a user would enter it."""
    direction = rng.normal(size=3)
    direction /= np.linalg.norm(direction)
    kind = rng.integers(4)
    if kind == 0:
        return Velocity()
    if kind == 3 and fast:
        gap = 10.0 ** -rng.uniform(2, 9)  # 1 - beta
        gamma = 1.0 / np.sqrt(gap * (2.0 - gap))
        return Velocity(tuple(direction), lorentz_factor=float(gamma))
    return Velocity(tuple(direction * rng.uniform(0.0, 0.999)))


def random_geometry(rng, centre):
    kind = rng.integers(5)
    size = rng.uniform(0.1, 3.0)
    if kind == 0:
        return uv_sphere(centre, size, int(rng.integers(3, 12)), int(rng.integers(2, 8)))
    if kind == 1:
        return box(centre, rng.uniform(0.05, 3.0, size=3))
    if kind == 2:
        return quad(centre, (size, rng.uniform(0.1, 3.0)), normal_axis=int(rng.integers(3)))
    if kind == 3:  # a triangle soup, some of it degenerate
        n = int(rng.integers(1, 30))
        v = centre + rng.normal(scale=size, size=(3 * n, 3))
        t = np.arange(3 * n).reshape(n, 3)
        repeat = rng.random(n) < 0.2
        t[repeat, 2] = t[repeat, 0]  # zero-area triangles with a repeated corner
        v[rng.integers(3 * n)] = v[rng.integers(3 * n)]  # coincident vertices
        return v, t
    v, t = box(centre, (size, size, 1e-9))  # (almost) flat box: zero-area sides
    return v, t


def random_scene(rng):
    materials = [Material()]
    for _ in range(int(rng.integers(0, 3))):
        materials.append(Material(
            base_color=tuple(rng.uniform(0, 1, 3)), metallic=float(rng.uniform()), roughness=float(rng.uniform()),
            transmission=float(rng.choice([0.0, 1.0])), ior=float(rng.uniform(1.0, 2.5)),
            emission=tuple(rng.uniform(0, 3, 3) * (rng.random() < 0.3))))
    meshes = []
    light_speed = float(10.0 ** rng.uniform(-1, 2))
    for i in range(int(rng.integers(0, 5))):
        centre = rng.uniform(-6, 6, size=3)
        v, t = random_geometry(rng, centre)
        mesh = Mesh(f"M{i}", v, t, velocity=random_velocity(rng), pivot=tuple(centre),
                    material_indices=rng.integers(0, len(materials), size=len(t)))
        roll = rng.random()
        if roll < 0.15:  # an animated world line: a random smooth path below 0.95 c
            tau = np.linspace(-60, 20, 41)
            beta = np.cumsum(rng.normal(scale=0.1, size=(41, 3)), axis=0)
            beta *= 0.95 * rng.uniform() / max(np.linalg.norm(beta, axis=1).max(), 1e-9)
            path = centre + np.concatenate([[np.zeros(3)], np.cumsum(beta[:-1] * np.diff(tau)[:, None], axis=0)])
            mesh.trajectory = Trajectory(tau, path - path[np.argmin(abs(tau))] + centre, name=mesh.name)
            mesh.velocity = Velocity()
        elif roll < 0.3:  # a spin well below the rim-speed limit
            radius = float(np.linalg.norm(v - centre, axis=1).max()) + 1e-9
            axis = rng.normal(size=3)
            mesh.angular_velocity = tuple(axis / np.linalg.norm(axis) * rng.uniform(0, 0.9) * light_speed / radius)
        meshes.append(mesh)
    lights = []
    for i in range(int(rng.integers(0, 3))):
        kind = str(rng.choice(["POINT", "SUN", "SPOT", "AREA"]))
        lights.append(Light(f"L{i}", kind, tuple(rng.uniform(-8, 8, 3)), power=float(10 ** rng.uniform(0, 3)),
                            radius=float(rng.uniform(0, 1)), velocity=random_velocity(rng)))
    position = rng.uniform(-10, 10, 3)
    tau_obs = float(rng.uniform(-5, 5) if rng.random() < 0.7 else rng.uniform(-50, 50))
    # mostly aimed at where an object is seen (its pivot's retarded position), sometimes anywhere
    target = position + rng.normal(size=3)
    if meshes and rng.random() < 0.85:
        mesh = meshes[int(rng.integers(len(meshes)))]
        target = np.asarray(mesh.pivot, dtype=float)
        if mesh.trajectory is None and not mesh.velocity.is_zero:
            beta = np.asarray(mesh.velocity.beta, float)
            if mesh.velocity.lorentz_factor > 0:
                g = mesh.velocity.lorentz_factor
                beta = beta / np.linalg.norm(beta) * np.sqrt((g - 1) * (g + 1)) / g
            t = tau_obs
            for _ in range(200):  # fixed point of t = tau_obs - |X(t) - camera| (a contraction for b < 1)
                t = tau_obs - np.linalg.norm(target + beta * t - position)
            target = target + beta * t
        target = target + rng.normal(scale=0.3, size=3)
    camera = look_at_camera(position, target, fov_half_tan=float(rng.uniform(0.1, 1.5)),
                            velocity=random_velocity(rng) if rng.random() < 0.3 else Velocity())
    return Scene(camera=camera, meshes=meshes, materials=materials, lights=lights,
                 world_color=tuple(rng.uniform(0, 0.5, 3)), tau_obs=tau_obs, light_speed=light_speed)


def random_settings(rng):
    return RenderSettings(resolution=(int(rng.integers(1, 12)), int(rng.integers(1, 9))),
                          samples=int(rng.integers(1, 3)), max_bounces=int(rng.integers(0, 3)),
                          doppler_mode=str(rng.choice(["OFF", "FACTOR", "SPECTRAL"])), spectral_samples=8,
                          searchlight=bool(rng.random() < 0.8), threads=1,
                          film_transparent=bool(rng.random() < 0.5))


def check(scene, passes, colour=True):
    for name, data in passes.items():
        assert np.all(np.isfinite(data)), f"{name} has NaN or inf"
    if colour:
        assert passes["Combined"].min() >= 0.0, "negative colour"
    hit = passes["Depth"][..., 0] < MISS_DEPTH
    doppler = passes["Doppler"][..., 0]
    assert np.all(doppler[hit] > 0.0), "D <= 0 on a hit"
    assert np.all(doppler[~hit] == 0.0), "D set where nothing is hit"
    observed = scene.tau_obs / scene.light_speed
    emitted = passes["Emission Time"][..., 0][hit].astype(np.float64)
    # float32 pass: allow its rounding at the observation time's magnitude
    assert np.all(emitted <= observed + 1e-6 * (1.0 + abs(observed))), "emitted after it was seen"


def test_random_scenes_never_crash_and_keep_the_invariants():
    hits = 0
    for seed in range(SEED, SEED + CASES):
        rng = np.random.default_rng(seed)
        scene = random_scene(rng)
        settings = random_settings(rng)
        try:
            passes = render_image(scene, settings)
            # SPECTRAL colours outside the Rec.709 gamut: see test_spectral_colours_are_never_negative
            check(scene, passes, colour=settings.doppler_mode != "SPECTRAL")
        except Exception as error:
            raise AssertionError(f"fuzz scene seed {seed} (RESTFRAME_FUZZ_SEED={seed}): "
                                 f"{type(error).__name__}: {error}") from error
        hits += int((passes["Depth"] < MISS_DEPTH).sum())
    print(f"fuzz: {CASES} scenes, {hits} pixels hit")
    assert hits > 0  # the scenes are not all empty views


def test_spectral_colours_are_never_negative():
    """A fuzz scene (seed 20261230) whose spectral render has a negative RGB component."""
    rng = np.random.default_rng(20261230)
    scene = random_scene(rng)
    settings = random_settings(rng)
    assert settings.doppler_mode == "SPECTRAL"
    passes = render_image(scene, settings)
    check(scene, passes)

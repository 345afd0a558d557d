"""Mutation testing: every physics mutant below must make the fast test suite fail.

Each mutant is a small source patch (file, exact old text, new text) that plants one physics
mistake.  The harness copies the repository (tracked and untracked, not ignored files) to a
temporary folder, applies one mutant at a time there (the working tree is never touched), runs
the mutant's tests from ``tests/core`` or ``tests/blender`` (``--full``: both folders whole) and
expects them to fail.  It exits non-zero if any mutant survives, if a patch's old text is not
found exactly once (a refactor must retarget the mutant, never silently disable it), or if the
unmutated tests do not pass::

    tools/dev.sh tools/mutants.py                    # every mutant
    tools/dev.sh tools/mutants.py sun-d4 wigner      # some, by name
    tools/dev.sh tools/mutants.py --list             # names, what they break, their tests
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
FAST_SUITE = ("tests/core", "tests/blender")
TIMEOUT = 600  # seconds per mutant: a mutant that hangs the tests is reported, not waited for


@dataclass(frozen=True)
class Patch:
    file: str  # relative to the repository root
    old: str  # must occur exactly once in the file
    new: str


@dataclass(frozen=True)
class Mutant:
    name: str
    what: str  # the physics mistake it plants
    patches: tuple[Patch, ...]
    tests: tuple[str, ...]  # pytest node ids or files (from tests/core or tests/blender) that must fail


CORE = "restframe_addon/core/"
MOTION_QUERY = "restframe_addon/motion_query.py"
LORENTZ, FRAMES, TRACER, SHADING, RENDER, COLOUR, PASSES, PREPARED, VALIDATION = (
    CORE + m for m in ("lorentz.py", "frames.py", "tracer.py", "shading.py", "render.py", "colour.py", "passes.py",
                       "prepared.py", "validation.py"))
T_RENDER, T_SHADING, T_LORENTZ = ("tests/core/" + m for m in ("test_render.py", "test_shading.py", "test_lorentz.py"))
T_SPECTRAL = "tests/core/test_spectral.py"
T_OBSERVERS = "tests/core/test_observers.py"
T_LIGHTS = "tests/core/test_moving_lights.py"
T_STEREO_EYES = ("tests/blender/test_blender_observer.py::"
                 "test_each_stereo_eye_of_a_moving_camera_observes_from_its_own_world_line")


MUTANTS = (
    Mutant("visibility-by-rest-path", "hidden-surface order decided by the rest-frame path length s' instead of s",
           (Patch(TRACER, "nearer = s < (best if found is None else best[found if rays is None else rays[found]])",
                  "nearer = rest < (best if found is None else best[found if rays is None else rays[found]])"),),
           (f"{T_RENDER}::test_visibility_is_decided_by_the_observer_path_length_not_the_rest_frame_one",)),
    Mutant("wigner", "a moving observer mapped into an object frame by one boost of the composed velocity "
                     "(drops the Wigner rotation)",
           (Patch(FRAMES, "FrameMap([self._inverse[a], fb])",
                  "FrameMap([Boost.from_velocity(compose_velocities(fa.beta, fb.beta)[0])])"),
            Patch(FRAMES, "from .lorentz import Boost, events_of_boosts\n",
                  "from .lorentz import Boost, compose_velocities, events_of_boosts\n")),
           (T_OBSERVERS,)),
    Mutant("shadow-cull-at-rest", "shadow rays culled against a moving body's box as if it stood still",
           (Patch(TRACER, "np.add(d[first:, axis], v, out=e)", "np.copyto(e, d[first:, axis])"),),
           ("tests/core/test_occlusion_culling.py",)),
    Mutant("doppler-chain-last-step", "Doppler factors along a chain of boosts not multiplied (last step only)",
           (Patch(FRAMES, "w = w * step_w", "w = step_w"),),
           (T_OBSERVERS,)),
    Mutant("contraction-about-world-origin", "a moving body placed in its frame without the shift that keeps "
                                             "its pivot where the artist put it (contracted about the origin)",
           (Patch(FRAMES, "return boost.gamma_minus_one * float(boost.n @ pivot) * boost.n", "return np.zeros(3)"),),
           (T_OBSERVERS,)),
    Mutant("object-clock-pivot", "the object clock ignores the pivot's clock zero (Object Time pass)",
           (Patch(FRAMES, "clock = -clock_shift(boost, mesh.pivot)", "clock = 0.0"),),
           (T_OBSERVERS,)),
    Mutant("background-searchlight", "the searchlight power dropped on the background seen by a moving camera",
           (Patch(SHADING, "values[miss] = rows.scale(world, self.searchlight_power(doppler, 4))",
                  "values[miss] = world"),),
           (T_OBSERVERS,)),
    Mutant("background-doppler-sign", "the background's Doppler factor inverted for a moving camera",
           (Patch(SHADING, "doppler = 1.0 / to_world.rays(d[miss])[1]", "doppler = to_world.rays(d[miss])[1]"),),
           (T_OBSERVERS,)),
    Mutant("searchlight-everywhere", "the searchlight (D^4) dropped everywhere",
           (Patch(SHADING, "        if not self.searchlight:\n", "        if True:\n"),),
           (f"{T_SHADING}::test_light_moving_with_the_surface_shows_only_the_camera_doppler",)),
    Mutant("shadow-ray-present-position", "shadow rays aimed at the light's present instead of its retarded position",
           (Patch(SHADING, "        r = doppler * r_rest  # distance to the retarded position in the surface frame\n",
                  "        r = doppler * r_rest  # distance to the retarded position in the surface frame\n"
                  "        u0, u = self.frames.map(pl.frame, k).events(np.ones(n), np.zeros((n, 3)))  # its 4-velocity\n"
                  "        e_k = rows.normalized(rows.scale(e_k, r) + rows.scale(u, r / u0))  # where it is now\n"),),
           (T_LIGHTS,)),
    Mutant("shadow-ray-observation-time", "shadow rays start at the observation time instead of the hit event's",
           (Patch(SHADING, "        tau_hit = hit_times(hits, order)\n",
                  "        tau_hit = hit_times(hits, order)\n"
                  "        self.shadow_tau = rows.take(hits.tau_frame, order)  # the ray's start: the observation event\n"),
            Patch(SHADING, "tau_sel, ids_sel = rows.take(tau, sel),",
                  "tau_sel, ids_sel = rows.take(self.shadow_tau, sel),")),
           (T_LIGHTS,)),
    Mutant("point-light-d2", "point-light irradiance scaled by D^2 instead of D^4",
           (Patch(SHADING, "intensity * self.searchlight_power(doppler, 4) / np.maximum(r, 1e-300) ** 2",
                  "intensity * self.searchlight_power(doppler, 2) / np.maximum(r, 1e-300) ** 2"),),
           (T_LIGHTS,)),
    Mutant("light-distance-rest-frame", "the distance to a moving light taken in its rest frame (r' for r)",
           (Patch(SHADING, "        r = doppler * r_rest  # distance", "        r = r_rest  # distance"),),
           (T_LIGHTS,)),
    Mutant("area-light-cosine-surface-frame", "a moving area light's emission cosine taken in the surface's frame",
           (Patch(SHADING, "intensity = np.maximum(e_j @ z_axis, 0.0) / np.pi",
                  "intensity = np.maximum(back(e_j)[0] @ z_axis, 0.0) / np.pi"),),
           (T_LIGHTS,)),
    Mutant("sun-d4", "sun irradiance scaled by D^4 instead of D^2",
           (Patch(SHADING, "sun_strength = self.searchlight_power(doppler, 2)",
                  "sun_strength = self.searchlight_power(doppler, 4)"),),
           (f"{T_SHADING}::test_sun_seen_from_a_moving_surface_is_aberrated_and_scaled_by_d_squared",)),
    Mutant("spot-cone-surface-frame", "a moving spot light's cone taken about the surface-frame direction",
           (Patch(SHADING, "intensity = intensity * _spot_falloff(e_j @ z_axis, light.spot_size, light.spot_blend)",
                  "intensity = intensity * _spot_falloff(back(e_j)[0] @ z_axis, light.spot_size, "
                  "light.spot_blend)"),),
           (T_LIGHTS,)),
    Mutant("bounce-in-observer-frame", "bounce (mirror/glass) rays built from the observer's direction, not mapped "
                                       "into the surface's rest frame",
           (Patch(SHADING, "n_a, ng_a, d_a = ns[active], ng[active], d_k[active]",
                  "n_a, ng_a, d_a = ns[active], ng[active], self._observer_d[active]"),
            Patch(SHADING, "                values[s] += self._secondary(k, tau[s],",
                  "                self._observer_d = self.frames.map(k, self.frames.camera).rays(d_k[s])[0]\n"
                  "                values[s] += self._secondary(k, tau[s],")),
           (T_OBSERVERS,)),
    Mutant("bounce-traced-from-observer", "bounce rays traced as if their coordinates were the observer's",
           (Patch(SHADING, "values, _ = self.radiance(k, tau, origin, d, eps, np.inf,",
                  "values, _ = self.radiance(self.frames.camera, tau, origin, d, eps, np.inf,"),),
           (f"{T_SHADING}::test_approaching_mirror_doubles_the_doppler_shift",)),
    Mutant("emission-curve-frame-time", "the emission curve read at the frame time instead of the object's clock",
           (Patch(SHADING, "self.frames.frames[k].object_clock(tau[s], prim[s])", "tau[s]"),),
           (T_OBSERVERS,)),
    Mutant("texture-uv-swapped", "texture coordinates interpolated with the barycentrics swapped",
           (Patch(SHADING, "weights = [np.asarray(w, dtype=np.float64) for w in (first, u, v)]",
                  "weights = [np.asarray(w, dtype=np.float64) for w in (first, v, u)]"),),
           (T_OBSERVERS,)),
    Mutant("texture-uv-swapped-large-mesh",
           "texture coordinates of a mesh too large for UV tables interpolated with the barycentrics swapped",
           (Patch(SHADING, "column += np.multiply(u, cuv[:, 1, c], out=term)\n"
                           "        column += np.multiply(v, cuv[:, 2, c], out=term)\n",
                  "column += np.multiply(v, cuv[:, 1, c], out=term)\n"
                  "        column += np.multiply(u, cuv[:, 2, c], out=term)\n"),),
           ("tests/core/test_frames.py::test_hit_uvs_from_a_threads_uv_tables_are_bit_for_bit_the_per_hit_uvs",)),
    Mutant("doppler-pass-inverted", "D replaced by 1/D in the Doppler pass",
           (Patch(PASSES, 'values["Doppler"] = [hit_doppler(', 'values["Doppler"] = [1.0 / hit_doppler('),),
           (f"{T_RENDER}::test_doppler_head_on_approach_on_the_axis_ray",)),
    Mutant("factor-display-inverse", "the FACTOR grey display computed from 1/D",
           (Patch(RENDER, "doppler = ray_doppler(prepared.frames, hits)", "doppler = 1.0 / ray_doppler(prepared.frames, hits)"),
            Patch(PREPARED, "doppler = ray_doppler(frames, hits)[hits.frame >= 0]",
                  "doppler = 1.0 / ray_doppler(frames, hits)[hits.frame >= 0]")),
           (f"{T_RENDER}::test_factor_display_paints_d_across_the_frames_own_range",)),
    Mutant("emission-time-camera-frame", "the Emission Time pass left in the camera frame (not world time)",
           (Patch(PASSES, "to_world = frames.map(frames.camera, frames.world)", "to_world = frames.map(frames.camera, frames.camera)"),),
           (T_OBSERVERS,)),
    Mutant("camera-event-at-reference-position", "a moving camera observes from where it was at the reference time",
           (Patch(PREPARED, "world_event = position + camera_boost.b * camera_boost.n * scene.tau_obs",
                  "world_event = position"),),
           (T_OBSERVERS,)),
    Mutant("spectral-shift-inverted", "wavelengths divided by D instead of multiplied at a frame change",
           (Patch(COLOUR, "return lam * doppler[:, None]", "return lam / doppler[:, None]"),),
           (f"{T_SPECTRAL}::test_moving_black_body_looks_like_a_black_body_at_d_times_t",)),
    Mutant("spectral-density-power", "spectral radiance scaled by D^4 like integrated radiance (drops D^5's extra power)",
           (Patch(COLOUR, "    extra_power = 1\n", "    extra_power = 0\n"),),
           (f"{T_SPECTRAL}::test_moving_black_body_looks_like_a_black_body_at_d_times_t",)),
    Mutant("observation-time-fps-inverted", "Blender's frame clock converted with fps / fps_base the wrong way up",
           (Patch(MOTION_QUERY, "- rf.reference_frame) * scene.render.fps_base / scene.render.fps",
                  "- rf.reference_frame) * scene.render.fps / scene.render.fps_base"),),
           ("tests/blender/test_blender_render.py::test_frame_clock_moves_the_observation_time",)),
    Mutant("gamma-naive", "gamma from a naive floating-point 1 - b^2",
           (Patch(VALIDATION, "return float(1 - sum(Fraction(c) ** 2 for c in beta))",
                  "return 1.0 - sum(c * c for c in beta)"),),
           (f"{T_LORENTZ}::test_speed_and_gamma_match_reference",)),
    Mutant("simultaneity-dropped", "the boosted time without the relativity of simultaneity (gamma tau)",
           (Patch(LORENTZ, "return gamma * (tau - b * nx), gamma_minus_one * nx - gamma * b * tau",
                  "return gamma * tau, gamma_minus_one * nx - gamma * b * tau"),),
           (T_LORENTZ,)),
    Mutant("aberration-without-gamma", "the aberrated direction's perpendicular part not divided by gamma",
           (Patch(LORENTZ, "inverse = np.multiply(self.gamma, one_plus_bd, out=np.empty(shape))",
                  "inverse = np.multiply(1.0, one_plus_bd, out=np.empty(shape))"),),
           (T_LORENTZ,)),
    Mutant("world-jacobian-inverted", "a world direction drawn in S given the density 1/D^2 instead of D^2 in "
                                      "the moving surface's frame",
           (Patch(CORE + "world.py", "return pdf_world * doppler * doppler", "return pdf_world / (doppler * doppler)"),),
           ("tests/core/test_integrator.py::test_moving_lambertian_faces_receive_the_aberrated_doppler_shifted_world",
            "tests/core/test_world.py")),
    Mutant("path-searchlight-dropped", "the light a path brings across a frame crossing not multiplied by D^4",
           (Patch(CORE + "integrator.py",
                  "throughput = rows.scale(state.throughput, shader.searchlight_power(doppler, 4))",
                  "throughput = state.throughput"),),
           ("tests/core/test_integrator.py::test_emitter_samples_and_bounce_rays_agree_across_frames",
            "tests/core/test_integrator.py::test_moving_wall_bleeds_doppler_shifted_colour_onto_a_static_floor")),
    Mutant("path-wavelengths-unshifted", "the wavelengths of a path not scaled by D at a frame crossing",
           (Patch(CORE + "integrator.py", "lam = colour.shift(state.lam, doppler)", "lam = state.lam"),),
           ("tests/core/test_integrator.py::test_emitter_samples_and_bounce_rays_agree_across_frames",
            "tests/core/test_integrator.py::test_moving_wall_bleeds_doppler_shifted_colour_onto_a_static_floor")),
    Mutant("lamp-hit-searchlight", "a moving lamp found by a bounce ray brings its radiance times D^2, not D^4",
           (Patch(CORE + "integrator.py", "weight = radiance * self.shader.searchlight_power(doppler, 4) * mis.",
                  "weight = radiance * self.shader.searchlight_power(doppler, 2) * mis."),),
           ("tests/core/test_integrator.py::test_lamp_samples_and_bounce_rays_agree_across_frames",)),
    Mutant("lamp-mis-jacobian", "a bounce ray's MIS weight against a moving lamp's samples uses the lamp's density "
                                "in its own frame (no aberration Jacobian D^2)",
           (Patch(CORE + "integrator.py", "state.pdf[sel], frame_pdf(pdf_j, doppler))", "state.pdf[sel], pdf_j)"),),
           ("tests/core/test_integrator.py::test_lamp_samples_and_bounce_rays_agree_across_frames",)),
    Mutant("rough-glass-fresnel-dropped", "light refracted through a rough microfacet not weighed by 1 - Fresnel",
           (Patch(CORE + "bsdf.py", "through = 1.0 - fresnel_dielectric(rows.dot(view, h), eta)",
                  "through = np.ones(len(n))"),),
           ("tests/core/test_bsdf_glass.py",)),
    Mutant("coat-does-not-dim", "the lobes under a coat get all the light the coat also reflects",
           (Patch(CORE + "integrator.py", "under = (1.0 - albedo)[:, None]", "under = np.ones((n, 1))"),),
           ("tests/core/test_bsdf_glass.py::test_a_clear_coat_over_white_keeps_the_furnace_white",)),
    Mutant("ggx-half-vector-length", "the GGX half vector's cosine with the normal from |v + l|^2 = 1 + v.l (its "
                                     "factor 2 dropped)",
           (Patch(CORE + "bsdf.py", "    c2 /= half\n    c2 *= 0.5\n", "    c2 /= half\n"),),
           ("tests/core/test_bsdf.py::test_ggx_from_cosines_matches_the_half_vector_form",)),
    Mutant("texels-wrap-last-row", "a texture's bilinear lookup above its last pixel row blends in the last row "
                                   "again instead of wrapping to the first",
           (Patch(CORE + "world.py", "padded[-1, :-1, :channels] = image[0]",
                  "padded[-1, :-1, :channels] = image[-1]"),),
           ("tests/core/test_world.py::test_texels_look_up_the_bits_of_a_plain_bilinear_repeat_lookup",)),
    Mutant("stereo-eye-on-camera-world-line", "a stereo eye of an accelerating camera observing from the "
                                              "camera's world line, not its own",
           (Patch("restframe_addon/export/camera.py",
                  "trajectory = _world_line(camera_object, scene, matrix[:3, 3], warn=lambda message: None)",
                  "trajectory = camera.trajectory"),),
           (T_STEREO_EYES,)),
    Mutant("stereo-eye-in-first-eye-frame", "an accelerating stereo eye rendered in the first eye's momentary "
                                            "rest frame (its rest frames shared for the same keyed motion)",
           (Patch(PREPARED, "if observer.camera_velocity(camera, tau_obs) != observer.camera_velocity(prepared.scene."
                            "camera, tau_obs):", "if camera.velocity != prepared.scene.camera.velocity:"),),
           (T_STEREO_EYES,)),
)


# ---------------------------------------------------------------------------------------- running
@dataclass
class Outcome:
    mutant: Mutant
    killed: bool
    detail: str  # the killing test(s), or why the mutant counts as surviving
    seconds: float


def repository_files(root: Path) -> list[str]:
    """The files a checkout would have: tracked and untracked ones, not ignored ones."""
    listing = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=root,
                             check=True, capture_output=True).stdout.decode()
    return [name for name in listing.split("\0") if name and (root / name).is_file()]


def copy_repository(root: Path, target: Path) -> None:
    for name in repository_files(root):
        (target / name).parent.mkdir(parents=True, exist_ok=True)
        shutil.copy2(root / name, target / name)


def check_patches(root: Path, mutants) -> list[str]:
    """Every patch's old text must occur exactly once in its file: problems, one line each."""
    problems = []
    for mutant in mutants:
        for patch in mutant.patches:
            path = root / patch.file
            count = path.read_text().count(patch.old) if path.is_file() else -1
            if count != 1:
                where = "the file is missing" if count < 0 else f"found {count} times"
                problems.append(f"{mutant.name}: old text {patch.old.strip()[:60]!r} in {patch.file}: {where}")
        for test in mutant.tests:
            test_file = test.split("::")[0]
            if not test_file.startswith(FAST_SUITE) or not (root / test_file).exists():
                problems.append(f"{mutant.name}: its test file {test_file} is missing or not in {' or '.join(FAST_SUITE)}")
    return problems


def apply(copy: Path, mutant: Mutant) -> dict[Path, str]:
    """Apply the mutant's patches in the copy; returns the original texts to restore."""
    originals: dict[Path, str] = {}
    for patch in mutant.patches:
        path = copy / patch.file
        originals.setdefault(path, path.read_text())
        text = path.read_text()
        assert text.count(patch.old) == 1, f"{mutant.name}: {patch.file} changed under the harness"
        path.write_text(text.replace(patch.old, patch.new))
    return originals


def run_pytest(copy: Path, tests, stop_first: bool = True):
    """(return code, output) of pytest on the copy (no bytecode: a restored file is never read from a stale .pyc)."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", COLUMNS="400", PYTHONPATH=os.pathsep.join(
        [str(copy)] + ([os.environ["PYTHONPATH"]] if os.environ.get("PYTHONPATH") else [])))
    command = [sys.executable, "-m", "pytest", "-q", "-rfE", "-p", "no:cacheprovider", "--no-header",
               *(["-x"] if stop_first else []), *tests]
    try:
        result = subprocess.run(command, cwd=copy, env=env, capture_output=True, text=True, timeout=TIMEOUT)
    except subprocess.TimeoutExpired:
        return None, f"timed out after {TIMEOUT} s"
    return result.returncode, result.stdout + result.stderr


# a test failing with one of these has met a mistake in the mutant's own code, not caught the physics
_CRASHES = ("AttributeError", "NameError", "UnboundLocalError", "TypeError", "ImportError", "ModuleNotFoundError",
            "SyntaxError", "IndentationError")


def failed_tests(output: str) -> list[tuple[str, str]]:
    """(test, start of its message) of each failure in pytest's short summary."""
    return re.findall(r"^(?:FAILED|ERROR) (.+?)(?: - (.*))?$", output, flags=re.MULTILINE)


def run_mutant(copy: Path, mutant: Mutant, full: bool) -> Outcome:
    started = time.monotonic()
    originals = apply(copy, mutant)
    try:
        code, output = run_pytest(copy, FAST_SUITE if full else mutant.tests)
    finally:
        for path, text in originals.items():
            path.write_text(text)
    seconds = time.monotonic() - started
    failures = failed_tests(output)
    crashed = [f"{test} ({message[:70]})" for test, message in failures if message.startswith(_CRASHES)]
    if code == 1 and failures and not crashed:  # tests ran and failed on what they check: killed
        return Outcome(mutant, True, ", ".join(f"{t} ({m[:70]})" if m else t for t, m in failures), seconds)
    if crashed:
        return Outcome(mutant, False, f"NOT A KILL: the mutant's code crashed: {', '.join(crashed)}", seconds)
    if code == 0:
        return Outcome(mutant, False, "SURVIVED: every test passed", seconds)
    tail = output.strip().splitlines()[-1] if output.strip() else ""
    # collection errors, crashes, timeouts: not a test that catches the physics -- fix the mutant
    return Outcome(mutant, False, f"NOT A KILL (pytest exit {code}): {tail}", seconds)


def check_isolation(copy: Path) -> None:
    """The tests must import the package from the copy, never the working tree."""
    env = dict(os.environ, PYTHONDONTWRITEBYTECODE="1", PYTHONPATH=str(copy))
    where = subprocess.run([sys.executable, "-c", "import restframe_addon; print(restframe_addon.__file__)"],
                           cwd=copy, env=env, check=True, capture_output=True, text=True).stdout.strip()
    if not Path(where).resolve().is_relative_to(copy.resolve()):
        sys.exit(f"mutants: the package is imported from {where}, not from the copy {copy}")


def main(argv=None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("names", nargs="*", help="mutants to run (default: all)")
    parser.add_argument("--list", action="store_true", help="list the mutants and exit")
    parser.add_argument("--full", action="store_true", help="run the whole fast suite (tests/core, tests/blender) "
                                                            "for every mutant instead of its own tests")
    parser.add_argument("--no-baseline", action="store_true",
                        help="skip running the selected tests unmutated first (CI has just run the whole suite)")
    args = parser.parse_args(argv)
    by_name = {m.name: m for m in MUTANTS}
    assert len(by_name) == len(MUTANTS), "two mutants share a name"
    if args.list:
        for m in MUTANTS:
            print(f"{m.name}: {m.what}\n    tests: {' '.join(m.tests)}")
        return 0
    unknown = [n for n in args.names if n not in by_name]
    if unknown:
        parser.error(f"unknown mutants {unknown}; --list shows them")
    problems = check_patches(ROOT, MUTANTS)  # all of them, whichever run: a stale mutant fails loudly
    if problems:
        print("mutants: stale patches (retarget them at the current code):", *problems, sep="\n  ", file=sys.stderr)
        return 2
    chosen = [by_name[n] for n in args.names] if args.names else list(MUTANTS)
    started = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="restframe-mutants-") as tmp:
        copy = Path(tmp)
        copy_repository(ROOT, copy)
        check_isolation(copy)
        if not args.no_baseline:
            selection = list(FAST_SUITE) if args.full else sorted({t for m in chosen for t in m.tests})
            code, output = run_pytest(copy, selection, stop_first=False)
            if code != 0:
                print(output[-4000:], file=sys.stderr)
                print("mutants: the selected tests fail WITHOUT any mutant; fix them first", file=sys.stderr)
                return 2
            print(f"baseline: the {len(selection)} test selections pass unmutated ({time.monotonic() - started:.0f} s)",
                  flush=True)
        outcomes = []
        for mutant in chosen:
            outcome = run_mutant(copy, mutant, args.full)
            outcomes.append(outcome)
            print(f"{'killed  ' if outcome.killed else 'SURVIVED'} {mutant.name:32s} {outcome.seconds:6.1f} s  "
                  f"{outcome.detail}", flush=True)
    width = max(len(o.mutant.name) for o in outcomes)
    print(f"\n{'mutant':{width}s}  result    killing test(s)")
    for o in outcomes:
        print(f"{o.mutant.name:{width}s}  {'killed  ' if o.killed else 'SURVIVED'}  {o.detail}")
    survivors = [o.mutant.name for o in outcomes if not o.killed]
    print(f"\n{len(outcomes) - len(survivors)} of {len(outcomes)} mutants killed in {time.monotonic() - started:.0f} s")
    if survivors:
        print(f"mutants: survived: {', '.join(survivors)}", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""Depth of field from Blender's camera matches Cycles at rest: the blur disc of a defocused small
emitter (its size, its polygon and the polygon's turn, the anamorphic squeeze) and the sharp plane
of focus, measured from both engines' images of the same bpy scene."""

import math

import bpy
import numpy as np
import pytest

from blender_helpers import add_camera, render_rgba

RES = 64
LENS_MM, SENSOR_MM = 100.0, 36.0
FOCAL_PIXELS = LENS_MM / SENSOR_MM * RES  # pixels per unit of tan(angle) (horizontal fit, square image)
SAMPLES = 256


def emissive(name, strength=1.0):
    mat = bpy.data.materials.new(name)
    if bpy.app.version < (5, 0, 0):
        mat.use_nodes = True
    nodes = mat.node_tree.nodes
    nodes.remove(nodes["Principled BSDF"])
    emission = nodes.new("ShaderNodeEmission")
    emission.inputs["Strength"].default_value = strength
    mat.node_tree.links.new(emission.outputs[0], nodes["Material Output"].inputs["Surface"])
    return mat


def black_world(scene):
    scene.world = bpy.data.worlds.new("Black")
    scene.world.color = (0.0, 0.0, 0.0)
    if scene.world.node_tree is not None:
        scene.world.node_tree.nodes["Background"].inputs["Strength"].default_value = 0.0


def render(scene, tmp_path, engine, samples=SAMPLES):
    """The red channel of an F12 render with either engine, row 0 at the bottom."""
    scene.render.engine = engine
    if engine == 'CYCLES':
        scene.cycles.device = 'CPU'
        scene.cycles.samples = samples
        scene.cycles.use_adaptive_sampling = False
        scene.cycles.use_denoising = False
        scene.cycles.pixel_filter_type = 'BOX'  # one-pixel box, like RESTframe's stratified samples
        scene.cycles.filter_width = 1.0
        scene.cycles.max_bounces = 0
        scene.cycles.seed = 3
    else:
        scene.restframe.samples = samples
    return render_rgba(scene, tmp_path / f"{engine}.exr")[..., 0]


def spot_scene(scene, depth, radius, **dof):
    """A small emissive sphere at ``depth`` straight ahead of a camera with the given DOF settings."""
    scene.render.resolution_x = scene.render.resolution_y = RES
    black_world(scene)
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0),
                        lens=LENS_MM, sensor_width=SENSOR_MM, sensor_fit='HORIZONTAL', clip_start=0.01)
    camera.data.dof.use_dof = True
    for key, value in dof.items():
        setattr(camera.data.dof, key, value)
    bpy.ops.mesh.primitive_uv_sphere_add(radius=radius, location=(0.0, depth, 0.0), segments=32, ring_count=16)
    bpy.context.object.data.materials.append(emissive("Glow"))
    return camera


def moments(image):
    """(flux, centroid x, y, covariance 2x2) of an image, pixels."""
    h, w = image.shape
    y, x = np.mgrid[0:h, 0:w] + 0.5
    flux = image.sum()
    cx, cy = (image * x).sum() / flux, (image * y).sum() / flux
    dx, dy = x - cx, y - cy
    cov = np.array([[(image * dx * dx).sum(), (image * dx * dy).sum()],
                    [(image * dx * dy).sum(), (image * dy * dy).sum()]]) / flux
    return flux, cx, cy, cov


def blur_radius(pinhole, with_lens, polar_factor):
    """Radius of the aperture image the lens convolved the pinhole image with (mean squared radii add;
    a uniform disc has R^2 / 2, a regular hexagon 5 R^2 / 12)."""
    spread = np.trace(moments(with_lens)[3]) - np.trace(moments(pinhole)[3])
    return math.sqrt(spread / polar_factor)


def corner_angle(image, corners):
    """Angle (radians, image x right, y up) of a corner of an N-fold symmetric blur spot, from the
    phase of its N-th angular harmonic (weighted toward the rim, where the polygon shows)."""
    _, cx, cy, _ = moments(image)
    h, w = image.shape
    y, x = np.mgrid[0:h, 0:w] + 0.5
    dx, dy = x - cx, y - cy
    harmonic = (image * np.hypot(dx, dy) ** corners * np.exp(1j * corners * np.arctan2(dy, dx))).sum()
    return np.angle(harmonic) / corners


def outline(image):
    """The blur spot's pixels: brighter than half its level inside, after a 3x3 box (the sampling noise)."""
    padded = np.pad(image, 1)
    smooth = sum(padded[1 + dy:1 + dy + image.shape[0], 1 + dx:1 + dx + image.shape[1]]
                 for dy in (-1, 0, 1) for dx in (-1, 0, 1)) / 9
    return smooth > 0.5 * np.median(smooth[smooth > 0.25 * smooth.max()])


def test_hexagonal_bokeh_matches_cycles(scene, tmp_path):
    """6 blades turned by 0.3 rad, F/1 at 100 mm, focused at 0.5 m, emitter at 2.5 m: the hexagon's
    size (to 2%), its corners' direction and its outline equal Cycles'."""
    rotation, fstop, focus, depth = 0.3, 1.0, 0.5, 2.5
    camera = spot_scene(scene, depth, 0.04, focus_distance=focus, aperture_fstop=fstop,
                        aperture_blades=6, aperture_rotation=rotation)
    ours, cycles = render(scene, tmp_path, 'RESTFRAME', 1024), render(scene, tmp_path, 'CYCLES', 1024)
    camera.data.dof.use_dof = False
    ours_pinhole, cycles_pinhole = render(scene, tmp_path, 'RESTFRAME'), render(scene, tmp_path, 'CYCLES')
    hexagon = (1 + 2 * math.cos(math.pi / 6) ** 2) / 6
    radius_ours = blur_radius(ours_pinhole, ours, hexagon)
    radius_cycles = blur_radius(cycles_pinhole, cycles, hexagon)
    aperture = LENS_MM * 1e-3 / (2 * fstop)
    expected = aperture * (1 / focus - 1 / depth) * FOCAL_PIXELS
    print(f"hexagon circumradius: RESTframe {radius_ours:.3f} px, Cycles {radius_cycles:.3f} px, "
          f"thin lens {expected:.3f} px")
    assert radius_ours == pytest.approx(radius_cycles, rel=0.02)
    assert radius_ours == pytest.approx(expected, rel=0.02)
    turn_ours, turn_cycles = corner_angle(ours, 6), corner_angle(cycles, 6)
    sixty = math.pi / 3
    apart = (turn_ours - turn_cycles + sixty / 2) % sixty - sixty / 2
    print(f"hexagon corner at {math.degrees(turn_ours):.2f} deg (RESTframe), {math.degrees(turn_cycles):.2f} deg (Cycles)")
    assert abs(math.degrees(apart)) < 1.5
    # behind the focus the spot is the aperture upright: a corner at rotation + 30 degrees
    assert abs(math.degrees((turn_ours - (rotation + math.pi / 6) + sixty / 2) % sixty - sixty / 2)) < 1.5
    differ = np.count_nonzero(outline(ours) != outline(cycles))
    print(f"outline: {differ} of {np.count_nonzero(outline(cycles))} pixels differ")
    assert differ <= 0.04 * np.count_nonzero(outline(cycles))


def test_anamorphic_round_bokeh_with_a_focus_object_matches_cycles(scene, tmp_path):
    """A round aperture squeezed by ratio 2, focused on an object off the axis (its distance along
    the view axis counts): the ellipse's axes equal Cycles' (to 2%)."""
    camera = spot_scene(scene, 0.4, 0.005, aperture_fstop=1.0, aperture_ratio=2.0)
    focus = bpy.data.objects.new("Focus", None)
    focus.location = (0.3, 1.5, -0.2)  # 1.5 m along the view axis
    scene.collection.objects.link(focus)
    camera.data.dof.focus_object = focus
    ours, cycles = render(scene, tmp_path, 'RESTFRAME'), render(scene, tmp_path, 'CYCLES')
    camera.data.dof.use_dof = False
    ours_pinhole, cycles_pinhole = render(scene, tmp_path, 'RESTFRAME'), render(scene, tmp_path, 'CYCLES')
    # semi-axes of a uniform ellipse: 2 sqrt(variance) along each
    axes = {}
    for name, blurred, pinhole in (("ours", ours, ours_pinhole), ("cycles", cycles, cycles_pinhole)):
        cov = moments(blurred)[3] - moments(pinhole)[3]
        axes[name] = 2 * np.sqrt(np.diag(cov))
    aperture = LENS_MM * 1e-3 / (2 * 1.0)
    expected_up = aperture * (1 / 0.4 - 1 / 1.5) * FOCAL_PIXELS
    print(f"ellipse semi-axes (across, up): RESTframe {axes['ours']}, Cycles {axes['cycles']}, "
          f"thin lens ({expected_up / 2:.3f}, {expected_up:.3f}) px")
    np.testing.assert_allclose(axes["ours"], axes["cycles"], rtol=0.02)
    np.testing.assert_allclose(axes["ours"], [expected_up / 2, expected_up], rtol=0.02)


def edge_width(image):
    """10-90% width (pixels) of a vertical bright-to-dark edge, from the rows' mean profile."""
    profile = image.mean(axis=0)
    profile = (profile - profile.min()) / (profile.max() - profile.min())
    x = np.arange(len(profile)) + 0.5
    falling = np.interp([0.9, 0.1], profile[::-1], x[::-1])
    return abs(falling[1] - falling[0])


def test_the_plane_of_focus_is_sharp(scene, tmp_path):
    """An emissive card's edge at the focus distance is as sharp as without depth of field, in
    both engines; focused 40% farther, the same F/1 lens blurs it over several pixels."""
    scene.render.resolution_x = scene.render.resolution_y = RES
    black_world(scene)
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0),
                        lens=LENS_MM, sensor_width=SENSOR_MM, sensor_fit='HORIZONTAL', clip_start=0.01)
    dof = camera.data.dof
    dof.focus_distance, dof.aperture_fstop = 0.5, 1.0
    bpy.ops.mesh.primitive_plane_add(size=1.0, location=(-0.5 + 0.0013, 0.5, 0.0), rotation=(math.radians(90), 0, 0))
    bpy.context.object.data.materials.append(emissive("Card"))
    widths = {}
    for use_dof in (True, False):
        dof.use_dof = use_dof
        for engine in ('RESTFRAME', 'CYCLES'):
            widths[engine, use_dof] = edge_width(render(scene, tmp_path, engine, samples=64))
    dof.use_dof, dof.focus_distance = True, 0.7
    defocused = edge_width(render(scene, tmp_path, 'RESTFRAME', samples=64))
    print("edge 10-90% width (px):", {f"{engine}{' DOF' if use else ''}": round(width, 3)
                                      for (engine, use), width in widths.items()}, f"focused 40% off: {defocused:.3f}")
    for engine in ('RESTFRAME', 'CYCLES'):
        assert widths[engine, True] == pytest.approx(widths[engine, False], abs=0.05)
    assert defocused > 3 * widths['RESTFRAME', False]


@pytest.mark.parametrize("blades", [0, 5])
def test_equirectangular_depth_of_field_matches_cycles(scene, tmp_path, blades):
    """A panoramic camera blurs as Cycles' does: the aperture across each ray, focus on the sphere of
    the focus distance; an emitter 17 degrees off the view axis blurs into the same spot of the
    panorama (covariance to 3%, a pentagon's corners turned alike), A |1/f - 1/z| radians in radius."""
    width, height = 128, 64
    scene.render.resolution_x, scene.render.resolution_y = width, height
    black_world(scene)
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0), type='PANO',
                        panorama_type='EQUIRECTANGULAR', longitude_min=-0.6, longitude_max=0.6,
                        latitude_min=-0.3, latitude_max=0.3, lens=100.0, clip_start=0.01)
    dof = camera.data.dof
    dof.use_dof, dof.focus_distance, dof.aperture_fstop = True, 0.4, 1.0
    dof.aperture_blades, dof.aperture_rotation = blades, 0.2
    depth, off_axis = 2.0, 0.3
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.04, location=(-depth * math.sin(off_axis), depth * math.cos(off_axis), 0.0),
                                         segments=32, ring_count=16)
    bpy.context.object.data.materials.append(emissive("Glow"))
    images = {(engine, True): render(scene, tmp_path, engine) for engine in ('RESTFRAME', 'CYCLES')}
    dof.use_dof = False
    images.update({(engine, False): render(scene, tmp_path, engine) for engine in ('RESTFRAME', 'CYCLES')})
    spread = {engine: moments(images[engine, True])[3] - moments(images[engine, False])[3]
              for engine in ('RESTFRAME', 'CYCLES')}
    radians_per_pixel = 1.2 / width
    polar = 0.5 if blades < 3 else (1 + 2 * math.cos(math.pi / blades) ** 2) / 6  # mean squared radius / R^2
    radius = {engine: math.sqrt(np.trace(cov) / polar) * radians_per_pixel for engine, cov in spread.items()}
    expected = LENS_MM * 1e-3 / 2 * (1 / 0.4 - 1 / depth)
    print(f"panorama blur covariance (px^2): RESTframe {spread['RESTFRAME'].ravel()}, Cycles {spread['CYCLES'].ravel()}; "
          f"radius RESTframe {radius['RESTFRAME']:.4f} rad, Cycles {radius['CYCLES']:.4f} rad, thin lens {expected:.4f} rad")
    scale = np.trace(spread["CYCLES"])
    assert np.abs(spread["RESTFRAME"] - spread["CYCLES"]).max() < 0.03 * scale
    assert radius["RESTFRAME"] == pytest.approx(expected, rel=0.03)
    if blades:
        turns = {engine: corner_angle(images[engine, True], blades) for engine in ('RESTFRAME', 'CYCLES')}
        step = 2 * math.pi / blades
        apart = (turns["RESTFRAME"] - turns["CYCLES"] + step / 2) % step - step / 2
        print(f"pentagon corner: RESTframe {math.degrees(turns['RESTFRAME']):.2f} deg, Cycles {math.degrees(turns['CYCLES']):.2f} deg")
        assert abs(math.degrees(apart)) < 2.0


def test_depth_of_field_export_as_cycles_reads_it(scene):
    """F-stop to aperture radius (focal length in mm as 1e-3 units; orthographic 1 / (2 F-stop)),
    blades, rotation and ratio, a focus bone's distance along the view axis, nothing without DOF; the
    camera's Depth of Field panels show for RESTframe."""
    from blender_helpers import export_now
    camera = add_camera(scene, location=(1.0, 2.0, 3.0), rotation=(0.4, 0.0, 0.3), lens=35.0)
    assert export_now(scene)[0].camera.aperture_radius == 0.0
    dof = camera.data.dof
    dof.use_dof, dof.aperture_fstop, dof.aperture_blades, dof.aperture_rotation, dof.aperture_ratio = True, 2.0, 5, 0.5, 1.3
    exported = export_now(scene)[0].camera
    assert exported.aperture_radius == pytest.approx(0.035 / 4.0)
    assert (exported.aperture_blades, exported.aperture_rotation, exported.aperture_ratio) == (5, pytest.approx(0.5), pytest.approx(1.3))
    bpy.ops.object.armature_add(location=(0.0, 0.0, 0.0))
    rig = bpy.context.object
    rig.pose.bones[0].location = (0.0, 0.7, 0.0)  # pose the bone: its head moves
    bpy.context.view_layer.update()
    dof.focus_object, dof.focus_subtarget = rig, rig.pose.bones[0].name
    head = np.array((rig.matrix_world @ rig.pose.bones[0].matrix).translation)
    axis = np.array(camera.matrix_world.col[2][:3])
    expected = abs(float((np.array(camera.matrix_world.translation) - head) @ axis))
    assert export_now(scene)[0].camera.focus_distance == pytest.approx(expected, rel=1e-6)
    assert expected != pytest.approx(abs(float((np.array(camera.matrix_world.translation) - np.array(rig.location)) @ axis)))
    camera.data.type = 'ORTHO'
    assert export_now(scene)[0].camera.aperture_radius == pytest.approx(0.25)
    for panel in ("DATA_PT_camera_dof", "DATA_PT_camera_dof_aperture"):
        assert 'RESTFRAME' in getattr(bpy.types, panel).COMPAT_ENGINES


def test_orthographic_depth_of_field_matches_cycles(scene, tmp_path):
    """An orthographic camera at F/1 (aperture radius 1 / (2 F-stop) = 0.5 units, as Cycles) focused
    at 2 m blurs an emitter at 3 m into a disc of radius A |1 - z/f| = 0.25 units, as Cycles does."""
    scene.render.resolution_x = scene.render.resolution_y = RES
    black_world(scene)
    ortho_scale = 2.0
    camera = add_camera(scene, location=(0.0, 0.0, 0.0), rotation=(math.radians(90), 0.0, 0.0), type='ORTHO',
                        ortho_scale=ortho_scale, clip_start=0.01)
    dof = camera.data.dof
    dof.use_dof, dof.focus_distance, dof.aperture_fstop = True, 2.0, 1.0
    bpy.ops.mesh.primitive_uv_sphere_add(radius=0.03, location=(0.1, 3.0, -0.05), segments=32, ring_count=16)
    bpy.context.object.data.materials.append(emissive("Glow"))
    blurred = {engine: render(scene, tmp_path, engine, 1024) for engine in ('RESTFRAME', 'CYCLES')}
    dof.use_dof = False
    radius = {engine: blur_radius(render(scene, tmp_path, engine), blurred[engine], 0.5) for engine in blurred}
    expected = 0.5 * abs(1 - 3.0 / 2.0) * RES / ortho_scale
    print(f"orthographic blur radius: RESTframe {radius['RESTFRAME']:.3f} px, Cycles {radius['CYCLES']:.3f} px, "
          f"thin lens {expected:.3f} px")
    assert radius["RESTFRAME"] == pytest.approx(radius["CYCLES"], rel=0.02)
    assert radius["RESTFRAME"] == pytest.approx(expected, rel=0.02)

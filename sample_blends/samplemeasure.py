"""Measurements on rendered sample scenes, and the analytic predictions they are compared with.

Everything here is numpy on the passes read back from a render (samplelib.render_blend) and on
the scene geometry the make_*.py scripts define; the predictions never look at a render.
Shared by render_gallery.py (the tables in docs/gallery.md) and tests/samples.
"""

from __future__ import annotations

import math

import numpy as np

import make_bars
import make_own_scenes
import make_tiles
import samplelib as lib

# The paper's Doppler factor ranges (section 3.2.3)
PAPER_RANGES = {
    "tiles_toward_0.9c": (3.407, 4.359),
    "tiles_sideways_0.8c": (0.538, 0.703),
    "tiles_sideways_0.9c": (0.398, 0.50),
}


# --------------------------------------------------------------------------- Doppler ranges
def field_range(velocity) -> tuple[float, float]:
    """Analytic range of D over the whole (continuous) square field of view of the tile scenes.

    Toward the camera (velocity along the axis): D = 1 / (gamma (1 - b cos a)), a = the angle off
    axis: largest on the axis, gamma (1 + b), smallest at the corners (a = corner angle).
    Sideways (velocity along X): D = 1 / (gamma (1 + b d_x)); over a square pinhole image |d_x| is
    largest at the middle of the left and right edges, d_x = +-sin(half field of view).
    """
    v = np.asarray(velocity, dtype=float)
    b = float(np.linalg.norm(v))
    g = lib.gamma(b)
    if v[2] != 0:
        corner = math.radians(make_tiles.corner_angle_deg())
        return 1.0 / (g * (1.0 - b * math.cos(corner))), g * (1.0 + b)
    s = math.sin(math.radians(make_tiles.FIELD_OF_VIEW / 2))
    return 1.0 / (g * (1.0 + b * s)), 1.0 / (g * (1.0 - b * s))


def implied_angles(velocity, d_range) -> tuple[float, float]:
    """Angles (deg) between the velocity and the view ray that give the D values of ``d_range``:
    beta . d = (1 / (gamma D) - 1), so cos(angle) = (1 / (gamma D) - 1) / b  (clamped: the paper's
    4.359 is gamma (1 + beta) = 4.35890 rounded up, a hair beyond the possible maximum)."""
    b = float(np.linalg.norm(velocity))
    g = lib.gamma(b)
    return tuple(math.degrees(math.acos(max(-1.0, min(1.0, (1.0 / (g * d) - 1.0) / b)))) for d in d_range)


def tiles(passes, info, velocity) -> dict:
    """Measured range (Doppler pass over hit pixels), predicted D at the same pixel centres."""
    d = passes["Doppler"][..., 0]
    hit = d > 0
    predicted = lib.doppler_predicted(lib.pixel_directions(info), velocity)
    return {
        "measured": (float(d[hit].min()), float(d[hit].max())),
        "predicted_pixels": (float(predicted.min()), float(predicted.max())),  # every pixel centre of the image
        "predicted_hit": (float(predicted[hit].min()), float(predicted[hit].max())),  # those that hit a tile
        "field": field_range(velocity),
        "max_error": float(np.abs(d[hit] - predicted[hit]).max()),
        "coverage": float(hit.mean()),
        "grey": passes["Combined"][..., 0],
    }


# --------------------------------------------------------------------------- headlamp
def centre(passes, name, channel=0):
    a = passes[name]
    h, w = a.shape[:2]
    return float(a[h // 2, w // 2, channel])


def headlamp(passes_by_beta) -> list[dict]:
    """Axis pixel of each speed against the rest render: D = gamma (1 + beta) and the radiance
    ratio D^4 (a diffuse surface lit in its own frame: L = D^4 L', docs/physics.md#searchlight)."""
    rest = centre(passes_by_beta[0.0], "Combined")
    rows = []
    for beta, passes in passes_by_beta.items():
        d_pred = lib.gamma(abs(beta)) * (1.0 + beta)
        rows.append({
            "beta": beta,
            "D": centre(passes, "Doppler"), "D_pred": d_pred,
            "ratio": centre(passes, "Combined") / rest, "ratio_pred": d_pred ** 4,
            "mean": float(passes["Combined"][..., :3].mean()),
        })
    return rows


# --------------------------------------------------------------------------- bars
def bars(passes, info, kind) -> list[dict]:
    """Per row (Object Index = row + 1): pixels, D range, largest |D - 1/(gamma (1 + beta . d))|."""
    directions = lib.pixel_directions(info)
    index = np.rint(passes["Object Index"][..., 0]).astype(int)
    d = passes["Doppler"][..., 0]
    rows = []
    for row, velocity in enumerate(make_bars.row_velocities(kind)):
        sel = index == row + 1
        if not sel.any():
            rows.append({"row": row + 1, "velocity": velocity, "pixels": 0})
            continue
        predicted = lib.doppler_predicted(directions[sel], velocity)
        rows.append({
            "row": row + 1, "velocity": velocity, "pixels": int(sel.sum()),
            "range": (float(d[sel].min()), float(d[sel].max())),
            "max_error": float(np.abs(d[sel] - predicted).max()),
        })
    return rows


# --------------------------------------------------------------------------- own scenes
def sphere_outline(passes, info) -> dict:
    """Circle fit of the sphere's outline on the sky, and the aspect ratio of its flat image."""
    mask = np.rint(passes["Object Index"][..., 0]).astype(int) == 1
    radius, rms, count, _, _ = lib.outline_circle_fit(mask, lib.pixel_directions(info))
    rows, cols = np.nonzero(mask)
    pixel = lib.pixel_angle(info)
    _, _, _, axis, _ = lib.outline_circle_fit(mask, lib.pixel_directions(info))
    pred_radius, pred_axis = sphere_prediction(info)
    # the outline pixels are the sphere's own edge pixels: their centres lie half a pixel inside the edge
    radius += 0.5 * pixel
    return {"radius_deg": math.degrees(radius), "rms_px": rms / pixel, "outline_pixels": count,
            "pixel_deg": math.degrees(pixel),
            "radius_pred_deg": math.degrees(pred_radius),
            "axis_error_px": float(np.arccos(np.clip(axis @ pred_axis, -1, 1))) / pixel,
            "width_px": int(cols.max() - cols.min() + 1), "height_px": int(rows.max() - rows.min() + 1)}


def terrell_cube(passes, beta=0.9) -> dict:
    """Visible faces by their rest-frame normals (Normal pass): trailing (-x) against top (+z).

    Seen from far away across the motion the cube looks rotated by asin(beta): the trailing face
    shows with projected width 2 sin = 2 beta, the top with 2 cos = 2 / gamma, area ratio beta gamma.
    """
    normal = passes["Normal"][..., :3]
    hit = np.rint(passes["Object Index"][..., 0]).astype(int) == 1
    trailing = hit & (normal[..., 0] < -0.9)
    leading = hit & (normal[..., 0] > 0.9)
    top = hit & (normal[..., 2] > 0.9)
    return {"trailing": int(trailing.sum()), "leading": int(leading.sum()), "top": int(top.sum()),
            "ratio": trailing.sum() / max(top.sum(), 1), "ratio_pred": beta * lib.gamma(beta) if beta else 0.0}


def retarded_point(camera, start, velocity, tau_obs):
    """Where a point moving as start + velocity * tau (c = 1) is seen from ``camera`` at tau_obs:
    the root of |X(tau) - camera| = tau_obs - tau with tau < tau_obs."""
    p = np.asarray(start, float) - np.asarray(camera, float)
    v = np.asarray(velocity, float)
    # |p + v tau|^2 = (tau_obs - tau)^2  ->  (v.v - 1) tau^2 + 2 (p.v + tau_obs) tau + p.p - tau_obs^2 = 0
    a, b, c = v @ v - 1.0, 2.0 * (p @ v + tau_obs), p @ p - tau_obs ** 2
    roots = np.roots([a, b, c])
    tau = min(r.real for r in roots if abs(r.imag) < 1e-12 and r.real < tau_obs)
    return np.asarray(start, float) + v * tau, tau


def project(info, point):
    """(column, row) image coordinates (pixel centres at integers, row 0 = top) of a world point."""
    d = info["rotation"].T @ (np.asarray(point, float) - info["position"])
    u, v = d[0] / -d[2], d[1] / -d[2]
    width, height = info["resolution"]
    (x0, x1), (y0, y1) = info["x_range"], info["y_range"]
    return (u - x0) / (x1 - x0) * width - 0.5, (y1 - v) / (y1 - y0) * height - 0.5


def mirror(passes, info) -> dict:
    """Ball seen directly and in the mirror: image centroids against the retarded positions.

    Direct: the ball centre's retarded position from the camera.  Reflected: the retarded position
    from the camera's mirror image (the reflected path is as long as the straight path from the
    mirror image), mirrored back through the mirror plane.  The light speed is 12 units/s and the
    frame is 1 s after the reference time: tau_obs = 12.
    """
    m = make_own_scenes
    tau_obs = float(np.linalg.norm(np.subtract(m.MIRROR_BALL, m.MIRROR_CAMERA)))
    velocity = (m.MIRROR_BETA, 0.0, 0.0)
    cam = np.asarray(m.MIRROR_CAMERA, float)
    image_cam = cam.copy()
    image_cam[1] = 2 * m.MIRROR_Y - cam[1]
    direct, tau_d = retarded_point(cam, m.MIRROR_BALL, velocity, tau_obs)
    seen, tau_r = retarded_point(image_cam, m.MIRROR_BALL, velocity, tau_obs)
    reflected = seen.copy()
    reflected[1] = 2 * m.MIRROR_Y - seen[1]
    index = np.rint(passes["Object Index"][..., 0]).astype(int)
    rgb = passes["Combined"][..., :3]
    ball_direct = index == 1
    # anti-aliased edge pixels of the direct ball have the mirror at their centre: keep 3 px away
    near = np.zeros_like(ball_direct)
    for dy in range(-3, 4):
        for dx in range(-3, 4):
            near |= np.roll(np.roll(ball_direct, dy, axis=0), dx, axis=1)
    ball_mirror = (index == 2) & ~near & (rgb[..., 0] > 1.0) & (rgb[..., 0] > 5 * rgb[..., 1])

    def centroid(mask):
        rows, cols = np.nonzero(mask)
        return (float(cols.mean()), float(rows.mean())) if len(rows) else (math.nan, math.nan)

    return {"direct": centroid(ball_direct), "direct_pred": project(info, direct), "direct_tau": tau_d,
            "mirror": centroid(ball_mirror), "mirror_pred": project(info, reflected), "mirror_tau": tau_r,
            "direct_pixels": int(ball_direct.sum()), "mirror_pixels": int(ball_mirror.sum())}


def glass_bars(passes, info) -> dict:
    """Bars seen directly: D against 1/(gamma (1 + beta . d)); the glass (static) has D = 1 and shows
    the bars' orange through it."""
    index = np.rint(passes["Object Index"][..., 0]).astype(int)
    d = passes["Doppler"][..., 0]
    bars_px = index == 1
    glass = index == 2
    predicted = lib.doppler_predicted(lib.pixel_directions(info), (0.9, 0.0, 0.0))
    rgb = passes["Combined"][..., :3]
    orange = (rgb[..., 0] > 0.05) & (rgb[..., 0] > 2.0 * rgb[..., 2])
    return {"bars_pixels": int(bars_px.sum()), "bars_max_error": float(np.abs(d[bars_px] - predicted[bars_px]).max()),
            "glass_pixels": int(glass.sum()), "glass_D": (float(d[glass].min()), float(d[glass].max())),
            "orange_in_glass": float(orange[glass].mean())}


def panel_colour(passes) -> dict:
    """Mean colour of the panel (Object Index 1) and its chromaticity r = R / (R + G + B), b likewise."""
    index = np.rint(passes["Object Index"][..., 0]).astype(int)
    rgb = passes["Combined"][..., :3][index == 1].mean(axis=0)
    total = float(rgb.sum())
    return {"rgb": tuple(float(c) for c in rgb), "r": float(rgb[0]) / total, "b": float(rgb[2]) / total,
            "D": centre(passes, "Doppler")}


def face_image_area(info, corners_rest, velocity, tau_obs):
    """Image area (pixels^2) of a planar face given by its rest-frame corners (pivot at the origin),
    each corner seen at its own retarded position (shoelace over the projected corners; the face's
    edges map to very nearly straight lines at this distance)."""
    v = np.asarray(velocity, float)
    b = float(np.linalg.norm(v))
    g = lib.gamma(b) if b else 1.0
    n = v / b if b else np.zeros(3)
    pts = []
    for c in corners_rest:
        c = np.asarray(c, float)
        start = c - (1.0 - 1.0 / g) * (c @ n) * n  # contracted along the motion about the pivot
        seen, _ = retarded_point(info["position"], start, v, tau_obs)
        pts.append(project(info, seen))
    x, y = np.array(pts).T
    return 0.5 * abs(float(np.dot(x, np.roll(y, 1)) - np.dot(y, np.roll(x, 1))))


def terrell_prediction(info, beta=0.9) -> float:
    """Predicted trailing/top area ratio of the Terrell cube for this camera (tau_obs = 40)."""
    trailing = [(-1, -1, -2), (-1, 1, -2), (-1, 1, 0), (-1, -1, 0)]
    top = [(-1, -1, 0), (1, -1, 0), (1, 1, 0), (-1, 1, 0)]
    velocity = (beta, 0.0, 0.0)
    return face_image_area(info, trailing, velocity, 40.0) / face_image_area(info, top, velocity, 40.0)


def sphere_prediction(info, radius=1.5, beta=(0.9, 0.0, 0.0), tau_obs=12.0, samples=720):
    """Outline of a sphere (pivot at the origin event, moving with ``beta``) on the observer's sky,
    predicted without the renderer: in the sphere's rest frame it is static, so from the observation
    event the outline is the cone of half-angle asin(R / r') about the direction to the centre
    (r' = the distance there); each cone direction is aberrated back to the world frame
    (docs/physics.md#backward-light-rays, d' with -beta).  Returns (angular radius rad, unit axis) of the circle in S."""
    v = np.asarray(beta, float)
    b = float(np.linalg.norm(v))
    g = lib.gamma(b)
    k = g * g / (g + 1.0)
    cam = np.asarray(info["position"], float)
    cam_rest = cam + (k * (v @ cam) - g * tau_obs) * v  # the observation event in the sphere frame
    to_centre = -cam_rest / np.linalg.norm(cam_rest)
    half = math.asin(radius / np.linalg.norm(cam_rest))
    e1 = np.cross(to_centre, [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(to_centre, e1)
    phi = np.linspace(0.0, 2 * math.pi, samples, endpoint=False)[:, None]
    cone = math.cos(half) * to_centre + math.sin(half) * (np.cos(phi) * e1 + np.sin(phi) * e2)
    u = -v  # from the sphere frame back to S
    d = (cone + (k * (cone @ u)[:, None] + g) * u) / (g * (1.0 + cone @ u))[:, None]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    centre = d.mean(axis=0)
    _, _, vt = np.linalg.svd(d - centre)
    n = vt[2] if vt[2] @ centre > 0 else -vt[2]
    return float(np.arccos(np.clip(d @ n, -1, 1)).mean()), n

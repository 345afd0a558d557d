"""The observer on its world line: the camera frame, the observation event, and the events of
shutter samples of an accelerating camera (docs/physics.md#observer).

A camera at constant velocity moves on ``(tau, c_ref + beta tau)``.  An animated camera
(``Camera.trajectory``, its keyframed location) observes from its world line at the frame's
world time ``tau_obs``; the image forms in its momentary rest frame there, the tracer's camera
frame C: its velocity is the world line's at that event, its past acceleration enters nowhere.

With motion blur each sample of an animated camera observes at its own proper time on the world
line (the shutter runs on the camera's clock), in the camera's momentary rest frame M at that
event: the sample's ray is made in M, as the lens makes it, and mapped into C (events and
directions, through S) for tracing.  What it sees there is light in C's units; seen in M it is
Doppler shifted by ``D = s_M / s_C``, one factor more along the ray.
"""

from __future__ import annotations

import numpy as np

from .lorentz import Boost, RowBoosts
from .scene import Camera, Velocity


def proper_time(tau: float, velocity: Velocity, trajectory=None) -> float:
    """The own clock (c*t units) at world time ``tau`` of a camera, lamp or body pivot whose clock
    reads 0 at world time 0: along its world line, or ``tau / gamma`` at constant velocity."""
    if trajectory is not None:
        return float(trajectory.proper_time(np.array([tau]))[0])
    return tau / Boost.from_velocity(velocity.beta, velocity.lorentz_factor).gamma


def camera_velocity(camera: Camera, tau_obs: float) -> Velocity:
    """The velocity of the camera frame: constant, or the world line's at the observation event."""
    if camera.trajectory is None:
        return camera.velocity
    _, beta = camera.trajectory.state(np.array([tau_obs]))
    return Velocity(tuple(float(b) for b in beta[0]))


def observation_event(camera: Camera, boost: Boost, tau_obs: float):
    """(camera-frame time, camera-frame position) of an animated camera's observation event:
    its world line at world time ``tau_obs``."""
    position, _ = camera.trajectory.state(np.array([tau_obs]))
    tau, x = boost.events(np.array([tau_obs]), position)
    return float(tau[0]), x[0]


def shutter_samples(camera: Camera, boost: Boost, tau_obs: float, camera_position, proper_offsets,
                    origins, directions):
    """Rays of an animated camera's shutter samples, in the camera frame C.

    ``proper_offsets`` (c*t units) are the samples' times on the camera's clock from the
    observation event; ``origins`` and ``directions`` the rays as the lens makes them in the
    camera's rest frame (``camera_position`` its place there).  Returns (tau, origins,
    directions, w) in C, w = s_C / s_M the path-length ratio between C and the sample's
    momentary rest frame M (1/D of what M sees over what C sees).
    """
    trajectory = camera.trajectory
    proper = trajectory.proper_time(np.array([tau_obs]))[0] + proper_offsets
    world_tau = trajectory.world_time(proper)
    position, beta = trajectory.state(world_tau)
    to_world = RowBoosts(beta).inverse()
    # the ray's start: the lens's offset from the camera, at the sample's time in M
    offset = np.asarray(origins, dtype=np.float64) - camera_position
    d_tau, d_x = to_world.events(np.zeros(len(offset)), offset)
    tau, x = boost.events(world_tau + d_tau, position + d_x)
    d_world, w_world = to_world.rays(np.asarray(directions, dtype=np.float64))
    d, w_camera = boost.rays(d_world)
    return tau, x, d, w_world * w_camera

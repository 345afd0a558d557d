"""Numbers read off rendered images, shared by the core and the Blender-layer tests."""

import numpy as np


def streak_ends(profile):
    """Sub-pixel columns where a streak's column profile falls to half its level near each end."""
    lit = np.flatnonzero(profile > 0.02 * profile.max())
    ends = []
    for end, inward in ((lit[0], 1), (lit[-1], -1)):
        plateau = profile[end + 4 * inward:end + 12 * inward:inward].mean()
        i = end + 4 * inward
        while profile[i - inward] >= 0.5 * plateau:
            i -= inward
        ends.append(i + 0.5 - inward * (profile[i] - 0.5 * plateau) / (profile[i] - profile[i - inward]))
    return np.array(ends)

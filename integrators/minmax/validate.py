"""What ``minmax_epipolar`` cannot render, refused with the fix."""
from __future__ import annotations

import numpy as np


def check_scene(params, cap) -> None:
    """Raise ValueError for inputs the method does not support (the scene
    itself was validated by :class:`SceneParams`)."""
    if cap.spp != 1:
        raise ValueError(
            f"minmax_epipolar renders one sample per pixel centre (got {cap.spp} samples "
            "per pixel): set samples_per_pixel=1 and render with spp=1.")
    light = params.light
    if light.position is not None and not params.medium.contains(np.asarray(light.position)):
        raise ValueError(
            f"minmax_epipolar: the {light.kind} light at {np.asarray(light.position).tolist()} "
            "lies outside the medium box; its in-scattering table assumes the whole light "
            "path is in the medium: enlarge the boundary cube to enclose the light, or use "
            "epipolar_tree or raymarch.")

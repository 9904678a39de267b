"""What ``minmax_epipolar`` cannot render, refused with the fix."""
from __future__ import annotations


def check_scene(params, cap) -> None:
    """Raise ValueError for inputs the method does not support (the scene
    itself was validated by :class:`~integrators.core.scene_params.SceneParams`)."""
    if cap.spp != 1:
        raise ValueError(
            f"minmax_epipolar renders one sample per pixel centre (got {cap.spp} samples "
            "per pixel): set samples_per_pixel=1 and render with spp=1.")

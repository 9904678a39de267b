"""The talk's quality profiles (Yusov 2013, "Performance" tables).

Slices, samples per slice and shadow-map size of each profile, from the
table of the talk for the screen size nearest to the render's (2560×1600 on
a high-end GPU; 1366×768 and 1024×768 share one set).  ``light_rays`` (the
1D min/max map's texels per slice) follows the shadow-map size, as in the
talk (``D_ShadowMap × N_Slices``).

Every profile also selects the talk's *method* (:data:`TALK_METHOD`):
depth-break refinement alone, no re-march of pixels whose blended taps
disagree and epipolar sampling at every image size.  The plugin's own
defaults (profile ``none``) refine by visibility, re-march such pixels and
march every pixel of images smaller than their samples (correct first);
``talk`` is the talk's method at the default (automatic) sizes.
"""
from __future__ import annotations


#: (screen width, height) -> profile -> (slices, samples, shadow map size)
TALK_TABLES = {
    (2560, 1600): {"high_quality": (2048, 1024, 4096), "balanced": (1024, 1024, 2048),
                   "high_performance": (1024, 512, 1024)},
    (1366, 768): {"high_quality": (1024, 1024, 2048), "balanced": (512, 512, 1024),
                  "high_performance": (512, 256, 512)},
}
PROFILES = ("high_quality", "balanced", "high_performance")
#: the talk's method without its sizes
METHOD_PROFILES = ("talk",)
#: the method options every profile sets (explicit properties override)
TALK_METHOD = {"refinement": "depth", "remarch_disagreement": 1.0, "small_image_march": False}


def profile_settings(profile: str, width: int, height: int) -> dict:
    """The talk's settings of ``profile`` for the table nearest in pixel count."""
    if profile not in PROFILES:
        raise ValueError(f"Property 'profile' = '{profile}' is not one of {list(PROFILES)}.")
    size = min(TALK_TABLES, key=lambda wh: abs(wh[0] * wh[1] - width * height))
    slices, samples, sm = TALK_TABLES[size][profile]
    return dict(slices=slices, samples=samples, shadowmap_resolution=sm, light_rays=sm)

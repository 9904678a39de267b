"""Pixel footprints of renders and references, so every comparison is like
for like (DESIGN §2, "Error conventions").

- **pixel centres**: one un-jittered camera ray through each pixel centre
  (our integrators at 1 sample per pixel); its reference is the exact
  working reference at the pixel centres (``raymarch visibility=exact``,
  rendered as two identical 1-spp chunks: deterministic, zero noise);
- **antialiased**: jittered samples box-filtered over the pixel (our
  integrators at > 1 spp, Mitsuba's own integrators at any spp); its
  reference is the box-filtered image volpath converges to (or the exact
  marcher with many jittered rays per pixel).

Comparing a 1-spp render with an antialiased reference measures aliasing
(every method scores alike); :func:`comparison_text` says which pair a
number comes from.
"""
from __future__ import annotations

PIXEL_CENTRES = "pixel centres"
ANTIALIASED = "antialiased"
#: (spp, chunk) of the exact reference at the pixel centres
PIXEL_CENTRE_SPP, PIXEL_CENTRE_CHUNK = 2, 1


def render_convention(integrator, scene, spp: int = 0) -> tuple[str, int]:
    """(convention, samples per pixel) of ``mi.render(scene, integrator,
    spp=spp)``.  Our integrators say how they sample
    (``sample_count``/``jitters``); Mitsuba's jitter every sample."""
    if hasattr(integrator, "sample_count") and hasattr(integrator, "jitters"):
        n = integrator.sample_count(scene, 0, spp)
        return (ANTIALIASED if integrator.jitters(n) else PIXEL_CENTRES), n
    n = int(spp) if spp else int(scene.sensors()[0].sampler().sample_count())
    return ANTIALIASED, n


def reference_convention(info: dict) -> str:
    """Convention of a reference from its sidecar (``kind``, ``chunk``): the
    exact marcher in 1-spp chunks samples the pixel centres, anything else is
    antialiased."""
    if info.get("kind") == "exact" and int(info.get("chunk") or 0) == 1:
        return PIXEL_CENTRES
    return ANTIALIASED


def pixel_centre_reference(scene_path: str, defines: dict | None, steps: int | None = None,
                           progress: bool = False):
    """(image, info) of the exact working reference at the pixel centres,
    rendered once and cached (:func:`episcatter.reference.render_reference`)."""
    from .reference import render_reference

    return render_reference(scene_path, defines, spp=PIXEL_CENTRE_SPP, chunk=PIXEL_CENTRE_CHUNK,
                            kind="exact", steps=steps, progress=progress)


def comparison_text(test: str, reference: str) -> str:
    """'pixel centres vs pixel centres (like for like)', or a warning."""
    if test == reference:
        return f"{test} vs {reference} (like for like)"
    return (f"MISMATCH: {test} render vs {reference} reference -- the error includes the "
            "difference of pixel footprints (aliasing), not only the method's")

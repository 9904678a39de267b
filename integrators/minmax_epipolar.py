"""minmax_epipolar: Yusov 2013, "Practical Implementation of Light Scattering
Effects Using Epipolar Sampling and 1D Min/Max Binary Trees".  The stages
live in :mod:`integrators.minmax`.
"""
from __future__ import annotations

import warnings
from dataclasses import replace

import drjit as dr
import mitsuba as mi
import numpy as np

from rectify import ring_mask

from .core.capture import capture_shadow_map
from .core.properties import read_bool, read_choice, read_number
from .core.quality_auto import register_rule
from .epipolar.ring import RING_BISECTIONS
from .minmax.integrate import integrate_samples
from .minmax.light_rays import MAX_ENTRY_EXPONENT, light_top, slice_light_rays, texel_count
from .minmax.minmax_tree import build_tree, colour_bounds, constant_colour
from .minmax.profiles import METHOD_PROFILES, PROFILES, TALK_METHOD, profile_settings
from .minmax.quality import MINMAX_RULE
from .minmax.refinement import (CRITERIA, THRESHOLD_MODES, depth_breaks, initial_samples,
                                inscattering_breaks, integrate_refined, interpolate,
                                interpolation_sources)
from .minmax.section_integral import point_table
from .minmax.slice_subset import (SliceState, computed_pixels, dirty_slices, merged_bounds,
                                  merged_rows, merged_samples)
from .minmax.slices_and_samples import sample_layout, trace_layout
from .minmax.unscattered import unshadowed_inscattering
from .minmax.unwarp import (DEPTH_SIGMA, disagreeing_pixels, fixup, frame_peak, march_every_pixel,
                            unwarp_taps)
from .minmax.validate import check_scene
from .template.base import CAMERA_OUTSIDE, EpiscatterIntegrator, warn_every_pixel_marched


#: samples on screen per pixel from which the defaults march every pixel
#: instead (:meth:`MinMaxEpipolarIntegrator.marches_every_pixel`)
SMALL_IMAGE_SAMPLES = 4


def beyond_table_range(params) -> bool:
    """Whether a point or spot light lies so many optical depths outside
    the medium box that a section's in-scattering underflows float32: the
    table (:mod:`.minmax.section_integral`) holds ``e^{-σt r}`` over the
    whole path from the light, and the texel colour's ``e^{σt r_in}`` that
    restores the path inside the box is capped at
    ``MAX_ENTRY_EXPONENT`` (:func:`~.minmax.light_rays.texel_colour`):
    ``σt (r₀ + diagonal)`` at or above the cap, with ``r₀`` the light's
    distance to the box, leaves the lit fog black.  Such frames are marched
    pixel by pixel (correct, at a marcher's cost), with a warning."""
    if params.light.kind == "directional":
        return False
    lo, hi = params.medium.bounds_min, params.medium.bounds_max
    p = np.asarray(params.light.position, np.float64)
    r0 = float(np.linalg.norm(np.maximum(lo - p, 0.0) + np.maximum(p - hi, 0.0)))
    depth = float(np.max(params.medium.sigma_t)) * (r0 + float(np.linalg.norm(hi - lo)))
    if depth < MAX_ENTRY_EXPONENT:
        return False
    warnings.warn(
        f"minmax_epipolar: the {params.light.kind} light is {r0:.3g} outside the fog box, "
        f"{depth:.0f} optical depths from its far side: beyond the range of the in-scattering "
        "table (float32), so every pixel is marched on its own (correct, but at a ray "
        "marcher's cost); epipolar_tree handles such scenes at its usual speed.", stacklevel=2)
    return True


#: steps of a whole-frame march the scene forces (:meth:`every_pixel`): the
#: epipolar template's ring steps
SCENE_MARCH_STEPS = 256


def scene_forced_march(params):
    """(why, fix) where the scene itself rules the slices out -- the camera
    outside the medium (the slices' samples start at the eye), a sun in a
    sphere or a mesh (no light-side path of three linear pieces) -- else
    None."""
    if params.camera_outside:
        return CAMERA_OUTSIDE
    if params.light.kind == "directional" and params.medium.boundary != "box":
        return (f"a sun in a {params.medium.boundary}-bounded medium has no light-side path "
                "of three linear pieces", 'bound the fog with a <shape type="cube">')
    return None


class MinMaxEpipolarIntegrator(EpiscatterIntegrator):
    r"""Epipolar sampling with 1D min/max binary trees (``minmax_epipolar``).

    Single scattering with volumetric shadows of a directional, point or
    spot light (with or without a projected texture) in the homogeneous
    medium around the camera, after Yusov 2013:

    1. *Slices and samples*: exit points on the border joined to the epipole
       (or its border crossing; the anti-epipole when the light is behind),
       ``samples`` per slice between entry and exit (border shrunk by half a
       pixel), rescaled to about one sample per pixel on short slices; each
       sample's camera ray is traced for its exact depth.
    2. *Refinement*: integration samples every ``initial_step`` samples
       (denser near the epipole, ``epipole_spacing``) plus those next to
       breaks of the chosen criterion; the others are interpolated linearly
       between their two nearest integration samples.
    3. *Blockers*: per slice a 1D height map of ``light_rays`` texels, the
       first blocker along each of the slice's light rays, traced with
       Mitsuba (``traced``) or read from a classic shadow map with
       conservative 2×2-filter bounds (``resampled``), and the light's colour
       (spot fall-off, projected texture) per texel.
    4. *Min/max tree* per slice and the *march* of every integration sample
       through it: whole nodes that are lit (with one colour) or shadowed are
       one section; each lit section's in-scattering is closed-form
       (directional, with the light-side path inside the medium box and any
       phase function) or two reads of a 2D table (point/spot: the talk's
       ``L[h, S]`` in the angle form ``C(h, φ)``).
    5. *Unwarp*: per pixel the two nearest slices × two samples with
       depth-aware (bilateral) weights; pixels whose weight sum is below
       ``fixup_threshold`` are ray-marched on their own (fix-up pass), and
       so are (beyond the talk) those whose blended taps disagree by more
       than ``remarch_disagreement`` -- a shadow edge or a thin beam runs
       between them, along the slices, and no blend estimates the pixel --
       with the epipolar methods' test and exact marcher
       (:func:`~integrators.epipolar.ring.disagreeing_samples`,
       :func:`~integrators.epipolar.ring.brute_force`).

    ==========================  ================================================
    ``profile``                 ``none`` (default), ``high_quality``,
                                ``balanced``, ``high_performance``: the talk's
                                slices / samples / shadow-map sizes for the
                                image size and the talk's method (``depth``
                                refinement, no disagreement re-march);
                                ``talk``: its method at the default sizes
                                (explicit properties override)
    ``slices``                  ``auto`` (default: sinh placement, every pixel
                                within half a pixel of a slice) or a count
                                of exit points along the border
    ``samples``                 samples per slice (default 0: the image
                                diagonal in pixels + 2)
    ``sample_density``          most samples per pixel along a slice (default 1:
                                the talk's rescaled exit points)
    ``initial_step``            samples between initial integration samples
                                (default 16; 1 integrates every sample)
    ``epipole_spacing``         near the epipole, integration samples at most
                                this fraction of their pixel distance to it
                                apart (default 0.25; 0: every
                                ``initial_step``, no densification)
    ``refinement``              ``visibility`` (default; the profiles:
                                ``depth``), ``depth`` or ``inscattering``
                                (see :mod:`.minmax.refinement`)
    ``refinement_threshold``    break threshold (default 0.03)
    ``threshold_mode``          ``relative`` (default) or ``absolute`` (depth)
    ``visibility_threshold``    relative difference of neighbouring results
                                that splits their interval (default 0.05)
    ``blockers``                ``traced`` (default) or ``resampled``
    ``light_rays``              texels per slice, a power of two (default 0:
                                above the image diagonal, at least 1024;
                                resampled: above the shadow map's size
                                along a slice)
    ``shadowmap_resolution``    classic shadow map size (resampled, fix-up)
                                (default 2048)
    ``min_max``                 use the tree (default true; false: march
                                every texel, the brute force along a slice)
    ``max_level``               highest tree level used (default -1: root)
    ``table_resolution``        point/spot table nodes per axis (default 256)
    ``depth_sigma``             relative depth scale of the bilateral weights
                                (default 0.03, the default depth-break
                                threshold)
    ``fixup_threshold``         bilateral weight sum below which a pixel is
                                re-marched (default 0.05)
    ``fixup_steps``             steps of the fix-up march (default 128)
    ``ring_degrees``            pixels this close to the epipole join the
                                fix-up (default 1; 0: none, as the talk)
    ``remarch_disagreement``    pixels whose blended taps (the two slices ×
                                two samples the unwarp weighs in) differ by
                                more than this fraction of the brighter join
                                the fix-up (default 0.25; the profiles: 1,
                                never)
    ``fixup_bisections``        bisections locating the shadow and cone
                                edges of the fix-up march (traced blockers;
                                default 4, the epipolar methods' ring)
    ``small_image_march``       march every pixel with the fix-up's marcher
                                when the slices hold at least 4 samples per
                                pixel (default true; the profiles: false):
                                on such small images each pixel spans a
                                wide angle between slices
    ==========================  ================================================

    One camera sample per pixel centre (the talk's convention).  The
    ``stats`` of :meth:`render_layers`'s result hold the counts of the render
    (integration samples, fix-up pixels, mean march steps; ``every_pixel_marched``
    when the frame was marched pixel by pixel).
    """

    RENAMED_PROPERTIES = {"rectification": "blockers"}

    def read_properties(self, props):
        self.profile = read_choice(props, "profile", "none",
                                   ("none",) + tuple(PROFILES) + METHOD_PROFILES)
        method = TALK_METHOD if self.profile != "none" else {}
        slices = props.get("slices", "auto")
        if slices != "auto":
            slices = read_number(props, "slices", 0, minimum=1, maximum=1 << 20, integer=True)
        self.slices = slices
        self.samples = read_number(props, "samples", 0, minimum=0, maximum=1 << 16, integer=True)
        self.sample_density = read_number(props, "sample_density", 1.0, minimum=1e-3,
                                          maximum=1e3)
        self.initial_step = read_number(props, "initial_step", 16, minimum=1, maximum=1 << 16,
                                        integer=True)
        self.epipole_spacing = read_number(props, "epipole_spacing", 0.25, minimum=0.0)
        self.refinement = read_choice(props, "refinement", method.get("refinement", "visibility"),
                                      CRITERIA)
        self.refinement_threshold = read_number(props, "refinement_threshold", 0.03, minimum=0.0)
        self.threshold_mode = read_choice(props, "threshold_mode", "relative", THRESHOLD_MODES)
        self.visibility_threshold = read_number(props, "visibility_threshold", 0.05, minimum=0.0)
        self.blockers = read_choice(props, "blockers", "traced", ("traced", "resampled"))
        self.light_rays = read_number(props, "light_rays", 0, minimum=0, maximum=1 << 16,
                                      integer=True)
        if self.light_rays & (self.light_rays - 1):
            raise ValueError(f"Property 'light_rays' = {self.light_rays} must be a power of "
                             "two (or 0 for the default).")
        self.shadowmap_resolution = read_number(props, "shadowmap_resolution", 2048, minimum=1,
                                                maximum=32768, integer=True)
        self.min_max = read_bool(props, "min_max", True)
        self.max_level = read_number(props, "max_level", -1, minimum=-1, maximum=30, integer=True)
        self.table_resolution = read_number(props, "table_resolution", 256, minimum=4,
                                            maximum=8192, integer=True)
        self.depth_sigma = read_number(props, "depth_sigma", DEPTH_SIGMA, minimum=1e-6)
        self.fixup_threshold = read_number(props, "fixup_threshold", 0.05, minimum=0.0)
        self.fixup_steps = read_number(props, "fixup_steps", 128, minimum=1, integer=True)
        self.ring_degrees = read_number(props, "ring_degrees", 1.0, minimum=0.0, maximum=90.0)
        self.remarch_disagreement = read_number(props, "remarch_disagreement",
                                                method.get("remarch_disagreement", 0.25),
                                                minimum=0.0, maximum=1.0)
        self.fixup_bisections = read_number(props, "fixup_bisections", RING_BISECTIONS,
                                            minimum=0, maximum=24, integer=True)
        self.small_image_march = read_bool(props, "small_image_march",
                                           method.get("small_image_march", True))
        self.explicit = {k for k in ("slices", "samples", "shadowmap_resolution", "light_rays")
                         if k in props}

    # -- stages -------------------------------------------------------------------
    def settings(self, params):
        """(slices, samples, light_rays, shadowmap_resolution) after the profile."""
        cam = params.camera
        s = dict(slices=self.slices, samples=self.samples, light_rays=self.light_rays,
                 shadowmap_resolution=self.shadowmap_resolution)
        if self.profile in PROFILES:
            for key, value in profile_settings(self.profile, cam.width, cam.height).items():
                if key not in self.explicit:
                    s[key] = value
        if not s["samples"]:
            s["samples"] = int((cam.width ** 2 + cam.height ** 2) ** 0.5) + 2
        if not s["light_rays"]:
            n = texel_count(cam.width, cam.height)
            if self.blockers == "resampled":
                n = max(n, texel_count(2 * s["shadowmap_resolution"], 0))
            s["light_rays"] = n
        return s

    def slices_alone(self) -> bool:
        """Whether a slice's values depend on that slice alone (and the
        frame-wide choices of :mod:`.minmax.slice_subset`): traced blockers
        and the ``depth`` or ``visibility`` criterion, whose breaks compare
        neighbours of one slice.  Otherwise a partial render computes the whole frame."""
        return self.blockers == "traced" and self.refinement in ("depth", "visibility")

    def scattering(self, params, cap):
        check_scene(params, cap)
        s = self.settings(params)
        shadow_map = None
        if self.blockers == "resampled":
            with self.stage("shadowmap"):
                shadow_map = capture_shadow_map(params, cap, s["shadowmap_resolution"])
        with self.stage("samples"):
            layout = sample_layout(params, s["slices"], s["samples"], self.sample_density)
        if self.marches_every_pixel(params, layout):
            return self.every_pixel(params, cap.entered(), layout, s, shadow_map)
        with self.stage("samples"):
            samples = trace_layout(params, layout)
        table = self.section_table(params)
        flags = self.refine(params, samples, table)
        rays = self.height_maps(params, samples, s, shadow_map)
        lo, hi = colour_bounds(rays.colour, rays.n)
        const = constant_colour(lo, hi)
        per_sample, counts = self.slice_values(params, samples, flags, rays, table, const,
                                               shadow_map)
        out = self.to_pixels(params, cap, samples, per_sample, shadow_map)
        if self.slices_alone():
            self.render_record.frame_state = SliceState(s, samples, per_sample, lo, hi)
            self.record(frame_choices=self.frame_choices(params, samples.frame, const))
        self.record(settings=s, slices=samples.slices.count, samples=samples.size,
                    fixup_pixels=out.fixup_count, **counts)
        return out.L

    def partial_scattering(self, params, cap, mask, moved=None):
        """Per slice (:mod:`.minmax.slice_subset`), given the last frame's
        :class:`~integrators.minmax.slice_subset.SliceState` (the render's
        ``frame_state``) where it fits: re-trace and recompute the slices
        whose half-plane meets a ``moved`` box, unwarp the masked pixels and
        those next to a recomputed slice.  Else the whole frame."""
        state = self.render_record.given
        s = self.settings(params)
        layout = sample_layout(params, s["slices"], s["samples"], self.sample_density)
        if not (self.slices_alone() and isinstance(state, SliceState) and state.fits(s, layout)
                and not self.marches_every_pixel(params, layout)):
            return super().partial_scattering(params, cap, mask, moved)
        with self.stage("scattering") as keep:
            check_scene(params, cap)
            with self.stage("widen"):
                rows = dirty_slices(layout, moved)
            lo, hi = state.colour_lo, state.colour_hi
            samples, per_sample = replace(state.samples, frame=layout.frame), state.values
            counts = {}
            if len(rows):
                with self.stage("samples"):
                    part = trace_layout(params, layout.rows(rows))
                table = self.section_table(params)
                flags = self.refine(params, part, table)
                rays = self.height_maps(params, part, s, None)
                lo, hi = merged_bounds(state, *colour_bounds(rays.colour, rays.n), rows)
                const = constant_colour(lo, hi)
                values, counts = self.slice_values(params, part, flags, rays, table, const)
                samples = merged_samples(state, part, rows, layout.frame)
                per_sample = merged_rows(state.values, values, rows, samples.count)
            else:
                const = constant_colour(lo, hi)
            with self.stage("widen") as keep_w:
                computed = computed_pixels(samples, mask, rows)
                pixels = dr.compress(computed)
                keep_w.append(pixels)
            out = self.to_pixels(params, cap, samples, per_sample, None, pixels)
            L_scat = dr.zeros(mi.Color3f, cap.count)
            if dr.width(pixels):
                dr.scatter(L_scat, out.L, pixels)
            keep.append(L_scat)
        self.render_record.frame_state = SliceState(s, samples, per_sample, lo, hi)
        self.record(frame_choices=self.frame_choices(params, layout.frame, const), settings=s,
                    slices=layout.slices.count, slices_computed=len(rows),
                    fixup_pixels=out.fixup_count, **counts)
        return L_scat, computed

    @staticmethod
    def frame_choices(params, frame, const) -> tuple:
        """What every slice's values are made from besides the slice itself
        (:mod:`.minmax.slice_subset`): the directional depths' light top and
        the frame's constant light colour (None: none)."""
        return (("u_top", light_top(params, frame) if frame.is_directional else 0.0),
                ("const", const))

    # -- stages -------------------------------------------------------------------
    def section_table(self, params):
        """Stage ``table``: the point/spot section table (None: directional)."""
        if params.light.kind == "directional":
            return None
        with self.stage("table"):
            return point_table(params, self.table_resolution)

    def refine(self, params, samples, table):
        """Stage ``refinement`` of the slices of ``samples``: the initial
        integration samples (a Bool per sample)."""
        with self.stage("refinement") as keep:
            flags = initial_samples(samples, self.initial_step, self.epipole_spacing)
            if self.refinement in ("depth", "visibility"):
                flags |= depth_breaks(samples, self.refinement_threshold, self.threshold_mode)
            if self.refinement == "inscattering":
                coarse = unshadowed_inscattering(params, samples, table)
                flags |= inscattering_breaks(samples, coarse, self.refinement_threshold)
            keep.append(flags)
        return flags

    def marches_every_pixel(self, params, layout) -> bool:
        """Whether every pixel is marched on its own: the camera outside the
        medium (the slices' samples start at the eye), a directional light
        in a sphere or a convex mesh (no light-side path of three linear
        pieces), a
        point or spot light beyond the section table's range (:func:`beyond_table_range`), or
        the slices' samples on screen (counted on the host from the
        layout) at least ``SMALL_IMAGE_SAMPLES`` per pixel.  On
        such small images every pixel spans a wide angle between slices, so
        the interpolation misses the pixel centres' values, while marching
        each pixel on its own, by the fix-up's exact marcher, costs no more
        than the samples would.  The choice depends on the
        camera and the light alone, so a partial render makes the full
        render's."""
        forced = scene_forced_march(params)
        if forced is not None:
            warn_every_pixel_marched("minmax_epipolar", *forced)
            return True
        if beyond_table_range(params):
            return True
        if not self.small_image_march:
            return False
        cam = params.camera
        return float(layout.on_screen.sum()) >= SMALL_IMAGE_SAMPLES * cam.width * cam.height

    def samples_alone(self, params) -> bool:
        """A frame marched pixel by pixel (:meth:`marches_every_pixel`) with
        traced blockers computes each camera sample from its own ray alone:
        a partial render then marches the masked samples alone."""
        if self.blockers != "traced":
            return False
        s = self.settings(params)
        layout = sample_layout(params, s["slices"], s["samples"], self.sample_density)
        return self.marches_every_pixel(params, layout)

    def every_pixel(self, params, cap, layout, s, shadow_map):
        """Stage ``fixup`` of a frame :meth:`marches_every_pixel` marches:
        L_scat of every camera sample by the fix-up's marcher -- with at
        least :data:`SCENE_MARCH_STEPS` steps where the scene itself rules
        the slices out (the camera outside the medium, a sun in a sphere or
        a mesh): every pixel is then the march's, as the other epipolar
        methods march them (their ring's steps)."""
        steps = self.fixup_steps
        if scene_forced_march(params) is not None:
            steps = max(steps, SCENE_MARCH_STEPS)
        with self.stage("fixup") as keep:
            out = march_every_pixel(params, cap, layout.frame, steps, shadow_map,
                                    self.fixup_bisections)
            keep.append(out.L)
        self.record(settings=s, slices=layout.slices.count, samples=0,
                    fixup_pixels=out.fixup_count, every_pixel_marched=True)
        return out.L

    def height_maps(self, params, samples, s, shadow_map):
        """Stage ``blockers`` of the slices of ``samples``: their 1-D
        height maps."""
        with self.stage("blockers"):
            return slice_light_rays(params, samples, s["light_rays"], self.blockers,
                                    shadow_map)

    def slice_values(self, params, samples, flags, rays, table, const, shadow_map=None):
        """Stages ``tree``, ``integrate`` and ``interpolate``: the value of
        every sample of ``samples``' slices (and the counts of the render);
        ``const``: the frame's constant light colour
        (:func:`~integrators.minmax.minmax_tree.constant_colour`)."""
        with self.stage("tree"):
            tree = build_tree(rays, None if self.min_max else 0, const=const)
        max_level = None if self.max_level < 0 else self.max_level

        def integrate(lanes):
            res = integrate_samples(params, samples, lanes, rays, tree, table, max_level,
                                    shadow_map)
            return res.L, res.steps

        with self.stage("integrate") as keep:
            done = integrate_refined(samples, flags, integrate, self.visibility_threshold,
                                     self.refinement == "visibility")
            keep.append(done.values)
        with self.stage("interpolate") as keep:
            sources = interpolation_sources(samples, done.flags)
            per_sample = interpolate(sources, done.values, samples.used)
            used = dr.zeros(mi.UInt32, 1)
            dr.scatter_reduce(dr.ReduceOp.Add, used, mi.UInt32(1), mi.UInt32(0), samples.used)
            keep += [per_sample, used]
        return per_sample, dict(used_samples=int(used[0]), integration_samples=done.count,
                                mean_steps=int(done.steps[0]) / max(done.count, 1),
                                refinement_rounds=done.rounds)

    def to_pixels(self, params, cap, samples, per_sample, shadow_map, pixels=None):
        """Stages ``unwarp`` and ``fixup`` of the pixels ``pixels`` (None:
        every pixel)."""
        with self.stage("unwarp") as keep:
            taps = unwarp_taps(samples, per_sample, cap.d, self.depth_sigma, pixels)
            keep += [taps.L, taps.weight, taps.darkest, taps.brightest]
        with self.stage("fixup") as keep:
            ring = ring_mask(samples.frame, self.ring_degrees) if self.ring_degrees > 0 else None
            if ring is not None and pixels is not None:
                ring = dr.gather(mi.Bool, ring, pixels)
            disagree = disagreeing_pixels(taps, self.remarch_disagreement,
                                          frame_peak(samples, per_sample))
            also = ring if disagree is None else disagree if ring is None else ring | disagree
            remarched = dr.zeros(mi.UInt32, 1)
            if disagree is not None:
                dr.scatter_reduce(dr.ReduceOp.Add, remarched, mi.UInt32(1), mi.UInt32(0),
                                  disagree)
            out = fixup(params, cap, samples.frame, taps.L, taps.weight, self.fixup_threshold,
                        self.fixup_steps, shadow_map, also, pixels, self.fixup_bisections)
            keep.append(out.L)
        self.record(remarched=int(remarched[0]))
        return out

    def to_string(self):
        return (f"MinMaxEpipolarIntegrator[profile={self.profile}, slices={self.slices}, "
                f"blockers={self.blockers}, output={self.output}]")


register_rule("minmax_epipolar", MINMAX_RULE)
mi.register_integrator("minmax_epipolar", lambda props: MinMaxEpipolarIntegrator(props))

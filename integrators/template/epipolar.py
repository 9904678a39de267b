"""The render skeleton both epipolar methods share (DESIGN §3).

:class:`EpipolarIntegrator` reads the properties common to ``epipolar_tree``
and ``fourier_filter`` (slices, light rays, SVD rank, epipole ring, shadow
map resolution) and implements :meth:`scattering`: rectify (every camera
sample becomes a query of its nearest slice, Baran §3/§8, or of both
neighbouring slices, weighted by its position between them), let the method
answer the queries (:meth:`integrate_queries`), march the epipole ring by
brute force (Baran §6), and scatter both back to the camera samples.

Partial renders (the template's sample mask, temporal reuse): a method
whose :meth:`EpipolarIntegrator.integrate_queries` takes a subset of the
rows (``ROW_SUBSETS``) computes only the rows that hold a masked sample or
whose light rays can meet what moved, with the frame-wide choices made on
the whole frame (:mod:`integrators.partial.row_subset`), and writes only the samples
those rows determine; the others compute the whole frame when any sample
is masked.

A camera outside the medium: every sample is marched from where its ray
enters the fog (:meth:`EpipolarIntegrator.marched_from_outside`).
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from ..core.properties import read_bool, read_number
from ..epipolar.frame import choose_slices, epipolar_frame_of
from ..epipolar.kernel.svd import SAMPLES
from ..epipolar.light_factor import lowest_light_side, samples_over_dropped
from ..epipolar.light_rays.directional import LIGHT_SIDE_RANGE
from ..epipolar.light_rays.local import cone_samples, resolve_lit_cone
from ..epipolar.queries import assign_queries
from ..epipolar.ring import (RING_BISECTIONS, disagreeing_samples, march_ring, peak_marched,
                             remarch_samples, to_samples, union_samples)
from ..partial.row_subset import (Rectification, dirty_rows, moved_rows, restrict_queries,
                                  reuse_rectification)
from .base import CAMERA_OUTSIDE, EpiscatterIntegrator, warn_every_pixel_marched


class EpipolarIntegrator(EpiscatterIntegrator):
    """Base of the epipolar methods; subclasses implement
    :meth:`integrate_queries` (and may refuse lights in :meth:`check_light`)."""

    #: default of ``slice_interpolation`` (each camera sample shared by its
    #: two neighbouring slices instead of answered by the nearest one)
    SLICE_INTERPOLATION = False
    #: default of ``remarch_disagreement``: with slice interpolation, a
    #: camera sample whose two slices' answers differ by more than this
    #: fraction of the larger is ray-marched like the ring (1: never)
    REMARCH_DISAGREEMENT = 0.25
    #: whether :meth:`integrate_queries` answers a
    #: :class:`~integrators.partial.row_subset.RowSubset` of the rows exactly as the
    #: whole frame's render does (per-slice partial renders)
    ROW_SUBSETS = False

    def read_properties(self, props):
        self.slices = read_number(props, "slices", 0, minimum=0, maximum=1 << 20, integer=True)
        self.light_rays = read_number(props, "light_rays", 0, minimum=0, maximum=32767,
                                      integer=True)
        self.svd_rank = read_number(props, "svd_rank", 0, minimum=0, maximum=SAMPLES,
                                    integer=True)
        self.svd_tolerance = read_number(props, "svd_tolerance", 1e-3, minimum=1e-12,
                                         maximum=1.0)
        self.ring_degrees = read_number(props, "ring_degrees", 2.0, minimum=0.0, maximum=90.0)
        self.ring_steps = read_number(props, "ring_steps", 256, minimum=1, integer=True)
        self.ring_bisections = read_number(props, "ring_bisections", RING_BISECTIONS,
                                           minimum=0, maximum=24, integer=True)
        self.shadowmap_resolution = read_number(props, "shadowmap_resolution", 2048,
                                                minimum=1, maximum=32768, integer=True)
        self.slice_interpolation = read_bool(props, "slice_interpolation",
                                             self.SLICE_INTERPOLATION)
        #: None: automatic (:meth:`slice_spacing_for`)
        self.slice_spacing = (read_number(props, "slice_spacing", 1.0, minimum=0.05,
                                          maximum=1e4) if "slice_spacing" in props else None)
        self.remarch_disagreement = read_number(props, "remarch_disagreement",
                                                self.REMARCH_DISAGREEMENT, minimum=0.0,
                                                maximum=1.0)
        self.read_method_properties(props)

    def read_method_properties(self, props) -> None:
        """Read the method's own properties (hook)."""

    def check_light(self, params) -> None:
        """Raise ValueError for lights the method does not support (hook)."""

    def integrate_queries(self, params, cap, queries, plan=None):
        """L_scat of every (non-ring) query (hook); ``plan``: what
        :meth:`choose_rows` returned with the rows.  With ``ROW_SUBSETS``
        ``queries`` may be a :class:`~integrators.partial.row_subset.RowSubset`
        (never with a ``plan``): the frame-wide choices are then made on its
        ``whole`` queries and recorded (``stats["frame_choices"]``)."""
        raise NotImplementedError

    def slice_spacing_for(self, cap) -> float:
        """Largest spacing [px] of the automatic slices for a capture:
        ``slice_spacing`` when given, else 1 px at one sample per pixel and
        1/√spp px with ``spp`` jittered samples per pixel.  Baran's bound
        (§8: every pixel within half a pixel of a slice) is then kept for
        the samples' own spacing, so that antialiased renders gain from
        their samples instead of interpolating all of them from slices a
        pixel apart."""
        if self.slice_spacing is not None:
            return self.slice_spacing
        spp = int(cap.spp)
        return 1.0 / spp ** 0.5 if spp > 1 and self.jitters(spp) else 1.0

    def choose_rows(self, params, cap):
        """(frame, slices, plan): the rows the camera samples are sorted into
        (hook): Baran's epipolar slices (§3, §8), no plan."""
        frame = epipolar_frame_of(params)
        slices = choose_slices(frame, self.slices, self.slice_spacing_for(cap))
        if not self.slices:
            slices = resolve_lit_cone(params, frame, slices)
        return frame, slices, None

    def rectify(self, params, cap):
        """Stage ``rectify``: (queries, plan) of the whole frame -- the rows
        (:meth:`choose_rows`) and every camera sample as their queries.  A
        partial render handed the last frame's rectification
        (``frame_state``) keeps it where it still holds
        (:func:`~integrators.partial.row_subset.reuse_rectification`); every render
        hands its own on."""
        record = self.render_record
        with self.stage("rectify"):
            frame, slices, plan = self.choose_rows(params, cap)
            queries = None
            if self.ROW_SUBSETS and plan is None:
                queries = reuse_rectification(params, record.given, frame, slices, cap,
                                              self.ring_degrees, self.slice_interpolation)
            if queries is not None:
                self.record(rectification_reused=True)
            else:
                queries = assign_queries(params, frame, slices, cap, self.ring_degrees,
                                         interpolate=self.slice_interpolation)
            self.record(rows=int(queries.n))
            if self.ROW_SUBSETS and plan is None:
                record.frame_state = Rectification.of(queries, cap, self.ring_degrees,
                                                      self.slice_interpolation)
        return queries, plan

    def samples_alone(self, params) -> bool:
        """The camera outside the medium: every sample is marched on its own
        (:meth:`marched_from_outside`)."""
        return bool(params.camera_outside)

    def marched_from_outside(self, params, cap):
        """Stage ``ring`` of a camera outside the medium: every camera sample
        marched from where its ray enters the medium (``cap.entered()``) by
        the ring's exact marcher (``ring_steps``, ``ring_bisections``).  The
        slices' light rays and queries assume integrals that start at the
        eye, so here the method is correct at a ray marcher's cost; a
        warning says so."""
        warn_every_pixel_marched(self.method_name, *CAMERA_OUTSIDE)
        with self.stage("ring") as keep:
            L = peak_marched(params, cap.entered(), epipolar_frame_of(params), self.ring_steps,
                             self.ring_bisections)
            keep.append(L)
        self.record(marched_from_outside=cap.count)
        return L

    def widen_samples(self, params, cap, mask, moved=None):
        """Per slice (``ROW_SUBSETS``, rows without a ``plan``): every sample
        of a row that holds a masked sample or whose slice meets a ``moved``
        box (:func:`~integrators.partial.row_subset.dirty_rows`); else the whole
        frame."""
        if not self.ROW_SUBSETS:
            return super().widen_samples(params, cap, mask, moved)
        queries, plan = self.rectify(params, cap)
        if plan is not None:
            return super().widen_samples(params, cap, mask, moved)
        return dirty_rows(queries, mask, moved_rows(queries, moved))[1]

    def partial_scattering(self, params, cap, mask, moved=None):
        if not self.ROW_SUBSETS:
            return super().partial_scattering(params, cap, mask, moved)
        with self.stage("scattering") as keep:
            self.check_light(params)
            queries, plan = self.rectify(params, cap)
            with self.stage("widen") as keep_w:
                if plan is not None:     # rows fitted to the whole frame: all of them
                    computed = super().widen_samples(params, cap, mask, moved)
                    sub = queries if dr.any(computed)[0] else restrict_queries(
                        queries, dr.zeros(mi.UInt32, 0), dr.zeros(mi.UInt32, 0))
                else:
                    rows, computed = dirty_rows(queries, mask, moved_rows(queries, moved))
                    ring = dr.compress(dr.gather(mi.Bool, computed, queries.ring_sample))
                    sub = restrict_queries(queries, rows,
                                           dr.gather(mi.UInt32, queries.ring_sample, ring))
                keep_w.append(computed)
            L_scat = dr.select(computed, self.integrate_rows(params, cap, sub, plan), 0.0)
            keep.append(L_scat)
        self.record(rows_computed=sub.n, rows=queries.n)
        return L_scat, computed

    def scattering(self, params, cap):
        self.check_light(params)
        if params.camera_outside:
            return self.marched_from_outside(params, cap)
        queries, plan = self.rectify(params, cap)
        return self.integrate_rows(params, cap, queries, plan)

    def integrate_rows(self, params, cap, queries, plan=None):
        """L_scat per camera sample of ``queries`` (a whole frame's, or a
        :class:`~integrators.partial.row_subset.RowSubset`) and of its ring samples."""
        parts = []
        if queries.n:
            values = self.remarch_disagreeing(params, cap, queries,
                                              self.integrate_queries(params, cap, queries, plan))
            if queries.weight is not None:
                values = values * queries.weight
            parts.append((queries.sample, values))
        with self.stage("ring"):
            # traced here; marched in the kernel that adds it into the samples
            if dr.width(queries.ring_sample):
                parts.append((queries.ring_sample,
                              march_ring(params, cap, queries, self.ring_steps,
                                         self.ring_bisections)))
        return to_samples(queries, parts)

    def march_dropped(self, params, queries, rays, frame=None,
                      light_side_range: float = LIGHT_SIDE_RANGE) -> int:
        """Have the camera samples whose query covers a light ray the
        light-side factor dropped ray-marched
        (:func:`~integrators.epipolar.light_factor.samples_over_dropped`:
        a thick medium seen toward a directional light); ``frame``: the
        whole frame's (queries, rays) where ``queries``, ``rays`` are a
        partial render's rows; ``light_side_range``: the c the light-side
        factor was made with; how many samples (0: none, no kernel)."""
        if getattr(rays, "h", None) is None:        # light rays of a point/spot light
            return 0
        fq, fr = frame if frame is not None else (queries, rays)
        mask = samples_over_dropped(params, queries, rays, lowest_light_side(fq, fr, fr.h),
                                    light_side_range)
        return 0 if mask is None else self.march_samples(mask)

    def march_samples(self, mask) -> int:
        """Have the camera samples of ``mask`` (a mask over the samples)
        ray-marched by :meth:`remarch_disagreeing`, with the samples it
        marches anyway (``RenderRecord.march``); how many there are."""
        samples = dr.compress(mask)
        self.render_record.march.append(samples)
        return dr.width(samples)

    def march_later(self, name: str, mask_of) -> None:
        """Have the camera samples of the mask ``mask_of()`` makes (a mask
        over the samples, e.g. written by a scatter over the queries)
        ray-marched as :meth:`march_samples` does, the mask made by the
        disagreement test's kernel over the queries
        (:meth:`remarch_disagreeing`); ``stats[name]`` counts the samples."""
        self.render_record.march_later.append((name, mask_of))

    def remarch_disagreeing(self, params, cap, queries, values):
        """Stage ``ring``: the (unweighted) query ``values`` with the camera
        samples whose two neighbouring slices disagree by more than
        ``remarch_disagreement`` ray-marched like the ring
        (:func:`~integrators.epipolar.ring.disagreeing_samples`,
        :func:`~integrators.epipolar.ring.remarch_samples`): a shaft edge or
        a narrow spot beam running along the slices lies between them, and
        the blend of a lit and a dark answer estimates neither side.  Only
        with ``slice_interpolation`` (a nearest-slice query has no second
        answer); ``stats["remarched"]`` counts the samples.  The samples the
        method asked to march (``RenderRecord.march``, e.g. the tree's
        unresolved sums; the masks of :meth:`march_later`, made by the
        disagreement test's kernel) are marched in the same pass.  A
        narrow spot light's few lit samples are marched too
        (:func:`~integrators.epipolar.light_rays.local.cone_samples`, chosen on
        the whole frame so that a partial render marches what the full one
        does)."""
        with self.stage("ring"):
            # the values, where the method left them unevaluated, with the
            # disagreement's test (one kernel over the queries)
            dr.schedule(values)
            # the masks asked for later (march_later), with the same kernel
            later, self.render_record.march_later = self.render_record.march_later, []
            later = [(name, mask_of()) for name, mask_of in later]
            cone = cone_samples(params, queries)     # its test with the disagreement's
            remarch = disagreeing_samples(queries, values, self.remarch_disagreement)
            remarch = union_samples(queries.n_samples, remarch, cone())
            self.record(remarched=dr.width(remarch))
            for name, mask in later:
                self.record(**{name: self.march_samples(mask)})
            # with the samples the method asked for (RenderRecord.march)
            asked, self.render_record.march = self.render_record.march, []
            remarch = union_samples(queries.n_samples, remarch, *asked)
            values = remarch_samples(params, cap, queries, values, remarch, self.ring_steps,
                                     self.ring_bisections)
            # the marched samples are evaluated here; the values they replace
            # are read by the kernel that sums the queries into their samples
        return values

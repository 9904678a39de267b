"""Per-point terms of the single-scattering integrand (DESIGN §1), in Dr.Jit.

For a point ``x`` inside the medium and the camera direction ``ω``:

* :func:`sample_light` — Mitsuba's own emitter query: direction ``wo`` to the
  light, distance (``inf`` for directional lights) and the radiance it
  delivers without the medium (``irradiance``, or ``intensity/r²`` times the
  spot falloff and projected texture).
* :func:`light_transmittance` — ``e^{-σt·τ(x)}``, ``τ`` = length of the path
  from ``x`` toward the light inside the medium (:func:`medium_interval`:
  an axis-aligned box, a rotated or sheared box, a sphere).
* :func:`visible_exact` — ray-traced visibility ``V(x)`` (occluders inside and
  outside the medium box; the null-BSDF box itself does not occlude).
* :func:`phase_eval` — the medium's phase function evaluated exactly as
  Mitsuba does (``wi = -ω``, ``wo`` toward the light).
* :func:`segment_weight` — ``∫_a^b e^{-σt s} ds`` in closed form, stable as
  ``σt → 0``.
"""
from __future__ import annotations

import drjit as dr
import mitsuba as mi

from .opaque import colour as color
from .opaque import point, scalar, vector


#: relative offset used to stop shadow rays short of the medium box.
BOX_EPS = 1e-4


def as_color3(value) -> mi.Color3f:
    """A Mitsuba ``Spectrum`` (or Float) as Color3f: in ``*_mono`` variants
    its one channel three times (the methods compute in Color3f; the
    template keeps one channel of the result)."""
    if isinstance(value, mi.Color3f):
        return value
    if dr.is_array_v(value) and dr.depth_v(value) > 1 and dr.size_v(value) == 1:
        value = value[0]
    return mi.Color3f(value)


def slabs(p, d, bmin, bmax):
    d = mi.Vector3f(d)
    d_safe = dr.select(dr.abs(d) < 1e-30, 1e-30, d)
    inv = dr.rcp(d_safe)
    t0 = (mi.Vector3f(bmin) - mi.Vector3f(p)) * inv
    t1 = (mi.Vector3f(bmax) - mi.Vector3f(p)) * inv
    return dr.max(dr.minimum(t0, t1)), dr.min(dr.maximum(t0, t1))


def sample_light(params, x, active=True):
    """(wo, dist, L) at world points ``x``: unit direction toward the light,
    distance to it (inf for directional) and Mitsuba's delivered radiance."""
    it = dr.zeros(mi.Interaction3f)
    it.p = x
    ds, spec = params.light.emitter.sample_direction(it, mi.Point2f(0.5, 0.5), active)
    dist = ds.dist
    if params.light.kind == "directional":
        # Mitsuba returns a finite ds.dist (about the scene diameter) here.
        dist = dr.full(mi.Float, dr.inf, dr.width(ds.dist))
    return ds.d, dist, as_color3(spec)


def medium_interval(params, p, d):
    """(t_near, t_far): where the line ``p + t·d`` (``d`` need not be unit)
    enters and leaves the medium's boundary; ``t_far < t_near`` for a line
    that misses it.  The boundary is convex: an axis-aligned box (the slab
    test), a closed convex mesh (its face planes' half-spaces), or the image
    of the cube ``[-1, 1]³`` or of the unit sphere under an affine map (``MediumParams.to_local``: a rotated, scaled or
    sheared box; a sphere) -- ``t`` is the same in the shape's own frame,
    where the test is the slab test or a quadratic."""
    med = params.medium
    if med.planes is not None:
        return _convex_interval(med.planes, p, d)
    if med.to_local is None:
        return slabs(p, d, point(med.bounds_min), point(med.bounds_max))
    A, b = med.to_local[:, :3], med.to_local[:, 3]
    rows = [vector(A[i]) for i in range(3)]
    p, d = mi.Vector3f(p), mi.Vector3f(d)
    p_l = mi.Vector3f(*(dr.dot(rows[i], p) + scalar(b[i]) for i in range(3)))
    d_l = mi.Vector3f(*(dr.dot(rows[i], d) for i in range(3)))
    if med.boundary == "box":
        return slabs(p_l, d_l, mi.Vector3f(-1.0), mi.Vector3f(1.0))
    # |p_l + t d_l|² = 1, in the stable form (no cancellation of -b ± √disc)
    a = dr.squared_norm(d_l)
    h = dr.dot(p_l, d_l)
    c = dr.squared_norm(p_l) - 1.0
    disc = h * h - a * c
    q = -(h + dr.copysign(dr.sqrt(dr.maximum(disc, 0.0)), h))
    t0 = dr.select(q != 0.0, c / q, 0.0)
    t1 = dr.select(a > 0.0, q / dr.maximum(a, 1e-30), 0.0)
    hit = disc >= 0.0
    far = dr.largest(mi.Float)          # a miss: finite, so that differences stay finite
    return (dr.select(hit, dr.minimum(t0, t1), far), dr.select(hit, dr.maximum(t0, t1), -far))


def _convex_interval(planes, p, d):
    """(t_near, t_far) of the line ``p + t·d`` against the half-spaces
    ``n·x <= c`` (rows of ``planes``, opaque): the latest entry and the
    earliest exit; a line parallel to a face and outside it misses."""
    far = dr.largest(mi.Float)
    p, d = mi.Vector3f(p), mi.Vector3f(d)
    t_near, t_far = mi.Float(-far), mi.Float(far)
    for row in planes:
        n = vector(row[:3])
        den, num = dr.dot(n, d), scalar(row[3]) - dr.dot(n, p)
        t = num / dr.select(den == 0.0, 1.0, den)
        t_near = dr.select(den < 0.0, dr.maximum(t_near, t), t_near)
        t_far = dr.select(den > 0.0, dr.minimum(t_far, t), t_far)
        t_far = dr.select((den == 0.0) & (num < 0.0), -far, t_far)
    return dr.select(t_far >= t_near, t_near, far), t_far


def medium_exit_distance(params, p, d):
    """Distance along unit ``d`` from ``p`` (inside the medium) to its
    boundary (:func:`medium_interval`)."""
    return dr.maximum(medium_interval(params, p, d)[1], 0.0)


def segment_box(params, x, wo, dist):
    """(τ, t_in, t_out): the part ``[t_in, t_out]`` of the segment
    ``x + s·wo``, ``s ∈ [0, dist]``, that lies inside the medium (its
    boundary: :func:`medium_interval`), and its length τ (the light-side
    path length in the medium)."""
    t_near, t_far = medium_interval(params, x, wo)
    t_in = dr.clip(t_near, 0.0, dist)
    t_out = dr.maximum(dr.clip(t_far, 0.0, dist), t_in)
    return t_out - t_in, t_in, t_out


def light_transmittance(params, tau):
    return dr.exp(-color(params.medium.sigma_t) * tau)


def box_segments(params, t_in, t_out, dist):
    """The pieces ``[a, b]`` of the segment ``[0, dist]`` (``dist`` may be
    inf) outside, inside and beyond the medium box (crossings ``t_in`` /
    ``t_out`` from :func:`segment_box`), each stopped ``BOX_EPS`` (relative
    to the scene size) short of the box: ray queries count the null-BSDF
    box as a surface.  A segment that never enters the box (``t_out <=
    t_in``) is one piece.  Empty pieces have ``b <= a``; the gaps left
    around the crossings are :func:`crossing_gaps`."""
    eps = scalar(BOX_EPS * params.scene_extent)
    far = dr.select(dr.isinf(dist), dr.largest(mi.Float), dist * (1 - BOX_EPS))
    miss = t_out <= t_in
    return ((mi.Float(0.0), dr.select(miss, far, t_in - eps)),
            (dr.select(t_in > 0, t_in + eps, 0.0), dr.select(t_out < dist, t_out - eps, far)),
            (dr.select(miss, far, t_out + eps), far))


def crossing_gaps(params, t_in, t_out, dist):
    """The gaps ``(c, valid)`` that :func:`box_segments` leaves: ``[c - eps,
    c + eps]`` around each box crossing ``c`` the segment makes (``eps =
    BOX_EPS`` · scene size)."""
    enters = t_out > t_in
    return ((t_in, enters & (t_in > 0)), (t_out, enters & (t_out < dist)))


def _gap_hit(params, x, wo, c, far, active):
    """(found, s): a non-null surface within ``BOX_EPS`` (relative) of the
    box crossing at ``c`` on the segment ``x + s·wo``, ``s <= far``, and
    its distance ``s``: two short rays, one toward the crossing from each
    side, each stopped by the first surface it meets -- the box itself
    (null BSDF: not a blocker) or a surface in front of it (the forward
    ray's hit first: the backward ray's lies behind the crossing)."""
    eps = scalar(BOX_EPS * params.scene_extent)
    lo = dr.maximum(c - eps, 0.0)
    hi = dr.minimum(c + eps, far)
    found_any = mi.Bool(False)
    s_hit = mi.Float(hi)
    for start, sign in ((lo, 1.0), (hi, -1.0)):
        ray = dr.zeros(mi.Ray3f)
        ray.o, ray.d = x + wo * start, wo * sign
        ray.maxt = dr.maximum(hi - lo, 0.0)
        on = mi.Bool(active) & (hi > lo) & ~found_any
        pi = params.scene.ray_intersect_preliminary(ray, active=on)
        null = mi.has_flag(pi.shape.bsdf().flags(), mi.BSDFFlags.Null)
        found = on & pi.is_valid() & ~null
        s_hit = dr.select(found, start + sign * pi.t, s_hit)
        found_any |= found
    return found_any, s_hit


def _near_boundary_bounds(params):
    """(lo, hi) Point3f of :meth:`~integrators.core.scene_params.SceneParams.surfaces_near_boundary`
    at the gap width, or None."""
    near = params.surfaces_near_boundary(BOX_EPS * params.scene_extent)
    if near is None:
        return None
    return point(near[0]), point(near[1])


def visible_exact(params, x, wo, dist, t_in, t_out, active=True):
    """Ray-traced V(x): True unless a non-null surface blocks ``x`` -> light,
    tested piecewise around the medium box (:func:`box_segments`).  Where
    a surface reaches the box's boundary
    (:meth:`~integrators.core.scene_params.SceneParams.surfaces_near_boundary`),
    the gaps around the crossings inside its bounds are tested too
    (:func:`_gap_hit`): an occluder sticking out of the medium box
    would otherwise let light through along the line where it crosses
    the box (random stress seeds 43, 54, 98)."""
    blocked = mi.Bool(False)
    pieces = box_segments(params, t_in, t_out, dist)
    for a, b in pieces:
        ray = dr.zeros(mi.Ray3f)
        ray.o, ray.d = x + wo * a, wo
        ray.maxt = dr.maximum(b - a, 0.0)
        # ray_test's result is undefined on inactive lanes: mask it again
        seg_active = mi.Bool(active) & ~blocked & (b > a)
        blocked |= seg_active & params.scene.ray_test(ray, seg_active)
    near = _near_boundary_bounds(params)
    if near is not None:
        lo, hi = near
        far = pieces[-1][1]
        for c, valid in crossing_gaps(params, t_in, t_out, dist):
            p = x + wo * c
            on = mi.Bool(active) & ~blocked & valid & dr.all((p >= lo) & (p <= hi))
            blocked |= on & _gap_hit(params, x, wo, c, far, on)[0]
    return ~blocked


#: :func:`visible_confirmed`'s sideways shift of the second shadow ray,
#: relative to the scene size: far above float rounding (~1e-7), far below
#: ``BOX_EPS`` and any feature a render resolves
CRACK_SHIFT = 1e-5

#: a fixed direction no scene is built along; its cross product with the
#: shadow ray's direction gives the sideways shift
_GENERIC_AXIS = (0.5773502, 0.6154797, -0.5365729)


def visible_shifted(params, x, wo, dist, active=True):
    """:func:`visible_exact` of the shadow ray shifted sideways by
    ``CRACK_SHIFT`` of the scene size to one side, and where that is
    blocked, to the other (:func:`visible_confirmed`)."""
    side = dr.cross(wo, mi.Vector3f(*_GENERIC_AXIS))
    side = dr.select(dr.squared_norm(side) > 1e-6, side, dr.cross(wo, mi.Vector3f(1, 0, 0)))
    shift = dr.normalize(side) * scalar(CRACK_SHIFT * params.scene_extent)
    def clear(y, active):
        # the shifted ray crosses the medium box elsewhere (by shift/sin at
        # grazing incidence: random grazing seeds 19, 74, 140, 283)
        _, y_in, y_out = segment_box(params, y, wo, dist)
        return visible_exact(params, y, wo, dist, y_in, y_out, active)

    seen = clear(x + shift, active)
    other = mi.Bool(active) & ~seen
    return seen | (other & clear(x - shift, other))


def visible_confirmed(params, x, wo, dist, t_in, t_out, active=True, confirm=True):
    """:func:`visible_exact`, with each lit verdict confirmed by a second
    shadow ray shifted sideways (:func:`visible_shifted`; where a shadow
    edge lies within the shift, the ray shifted the other way).  A ray
    through a shared edge of two triangles can slip between them (Mitsuba's
    ray-triangle tests are not watertight): a light inside a closed cube
    then lit one pixel of the working reference (random stress seeds 208,
    263 and 274, where the shadow ray ran along a face's diagonal).  Such a
    crack is a set of measure zero: both shifted rays miss it, while a point
    that is truly lit has a lit ray on at least one side.  ``confirm``: the
    lanes whose lit verdict is confirmed (the others keep
    :func:`visible_exact`'s)."""
    lit = visible_exact(params, x, wo, dist, t_in, t_out, active)
    ask = mi.Bool(active) & lit & confirm
    return lit & (~ask | visible_shifted(params, x, wo, dist, ask))


def phase_eval(params, omega, wo, x=None):
    """f_p(cos θ) with Mitsuba's convention wi = -ω (ω: camera ray direction)."""
    mei = dr.zeros(mi.MediumInteraction3f)
    mei.wi = -omega
    mei.sh_frame = mi.Frame3f(mei.wi)
    if x is not None:
        mei.p = x
    ctx = mi.PhaseFunctionContext(None)
    value = params.medium.phase.eval_pdf(ctx, mei, wo)[0]
    return as_color3(value)


def segment_weight(sigma_t, a, b):
    """∫_a^b e^{-σt s} ds per channel, exact, stable for σt·(b-a) -> 0."""
    L = b - a
    x = sigma_t * L
    small = x < 1e-4
    series = L * (1 - 0.5 * x + x * x / 6)
    exact = (1 - dr.exp(-x)) * dr.rcp(dr.select(small, 1.0, sigma_t))
    return dr.exp(-sigma_t * a) * dr.select(small, series, exact)


def first_blocker(params, origin, d):
    """(hit, point): first surface on the ray ``origin + s·d`` (s ≥ 0), the
    medium box excepted -- the occluders :func:`~integrators.core.light_transport.visible_exact`
    sees.  Like it, the ray is traced in pieces split at the box crossings
    (each stopped ``BOX_EPS`` short of the box), whose origins stay exactly
    on the line: re-spawning at the box (:func:`~integrators.core.capture.first_surface`)
    offsets the ray along the box normal, which moves grazing hits by
    ~1e-4·extent/tan(angle).  The gaps around the crossings are tested
    where a surface reaches the box (:func:`_gap_hit`, as in
    :func:`visible_exact`)."""
    inf = dr.full(mi.Float, dr.inf, dr.width(origin.x))
    _, t_in, t_out = segment_box(params, origin, d, inf)
    hit = mi.Bool(False)
    p = mi.Point3f(origin)
    pieces = box_segments(params, t_in, t_out, inf)
    near = _near_boundary_bounds(params)
    gaps = crossing_gaps(params, t_in, t_out, inf) if near is not None else ()
    # in order along the ray: piece, gap at t_in, piece, gap at t_out, piece
    steps = [("piece", pieces[0])]
    for k in range(2):
        if gaps:
            steps.append(("gap", gaps[k]))
        steps.append(("piece", pieces[k + 1]))
    for kind, (a, b) in steps:
        if kind == "gap":
            c, valid = a, b
            q = origin + d * c
            active = ~hit & valid & dr.all((q >= near[0]) & (q <= near[1]))
            found, s_hit = _gap_hit(params, origin, d, c, pieces[-1][1], active)
            found &= active
            p = dr.select(found, origin + d * s_hit, p)
            hit |= found
            continue
        active = ~hit & (b > a)
        ray = mi.Ray3f(origin + d * a, d)
        ray.maxt = dr.maximum(b - a, 0.0)
        # only the distance is needed: the preliminary intersection skips
        # computing the full surface interaction
        pi = params.scene.ray_intersect_preliminary(ray, active=active)
        found = active & pi.is_valid()
        p = dr.select(found, ray.o + ray.d * pi.t, p)
        hit |= found
    return hit, p

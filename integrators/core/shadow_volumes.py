"""Shadow volumes of a scene's occluders: boxes around shapes (or clusters
of their triangles), the planes of each box's shadow volume from the light,
and the clipping of view-ray segments against them (DESIGN §3).  Used by
the hybrid march and by the change mask of animations.

The shadow volume is bounded conservatively: each object is covered by
axis-aligned boxes (its bounding box, or the boxes of clusters of its
triangles, :func:`shape_boxes`), and each box ``B`` is extruded away from
the light to infinity:

* directional light toward ``l``: ``SV(B) = {x : x + s·l ∈ B for some s ≥ 0}``;
* point/spot light at ``p``: ``SV(B) = {p + λ(y − p) : y ∈ B, λ ≥ 1}``
  (the spot cone is ignored: conservative).

Both are convex polyhedra (the box's faces that face the light plus the
supporting planes through the light and the box's silhouette edges;
:func:`shadow_volume_planes`), so a camera segment meets one iff
Cyrus–Beck clipping against its planes leaves a non-empty interval
``[t0, t1]`` (:func:`clip_segments`, Dr.Jit, one kernel for any number of
volumes).  A light inside a box makes that volume everything.  Every box is
padded by ``PAD`` (relative to the medium box's diagonal) to absorb float
rounding of the ray tests.
"""
from __future__ import annotations

from dataclasses import dataclass

import drjit as dr
import mitsuba as mi
import numpy as np

from .light_transport import slabs
from .opaque import opaque_scalar


#: box padding relative to the medium box's diagonal (float rounding of ray tests)
PAD = 1e-4
#: plane slots per volume: 6 faces + 12 edge planes (:func:`shadow_volume_planes`;
#: :class:`ShadowVolumes` keeps the used ones)
PLANES_PER_VOLUME = 18

_EDGES = [(a, b) for a in range(8) for b in range(a + 1, 8)
          if bin(a ^ b).count("1") == 1]   # corner k = (x bit 0, y bit 1, z bit 2)


@dataclass(frozen=True)
class Boxes:
    """Axis-aligned boxes ``[lo[i], hi[i]]`` (NumPy float64, shape (n, 3))."""
    lo: np.ndarray
    hi: np.ndarray

    def __len__(self):
        return len(self.lo)

    @staticmethod
    def empty() -> "Boxes":
        return Boxes(np.zeros((0, 3)), np.zeros((0, 3)))

    @staticmethod
    def concat(parts) -> "Boxes":
        parts = [p for p in parts if len(p)]
        if not parts:
            return Boxes.empty()
        return Boxes(np.concatenate([p.lo for p in parts]), np.concatenate([p.hi for p in parts]))

    def padded(self, pad: float) -> "Boxes":
        return Boxes(self.lo - pad, self.hi + pad)


# -- bounding boxes of shapes ----------------------------------------------------
def _spread_bits(q: np.ndarray) -> np.ndarray:
    """10-bit integers -> every third bit (for 30-bit Morton codes)."""
    q = q.astype(np.int64) & 0x3FF
    q = (q | (q << 16)) & 0x030000FF
    q = (q | (q << 8)) & 0x0300F00F
    q = (q | (q << 4)) & 0x030C30C3
    return (q | (q << 2)) & 0x09249249


@dataclass(frozen=True)
class TriangleGroups:
    """A fixed grouping of a mesh's triangles into clusters (along a Morton
    order of their first vertices, so nearby triangles share a cluster):
    ``vertex_index`` lists the vertices of each cluster's triangles (each
    once), cluster by cluster, cluster ``g`` starting at ``starts[g]``.  Any grouping bounds the mesh
    (every triangle lies in its cluster's box); a grouping made at the rest
    pose stays tight under rigid motion, so animations make it once."""
    vertex_index: np.ndarray
    starts: np.ndarray

    @staticmethod
    def of(vertices: np.ndarray, faces: np.ndarray, clusters: int) -> "TriangleGroups":
        vertices = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)
        faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
        clusters = int(max(1, min(clusters, len(faces))))
        order = np.arange(len(faces))
        if clusters > 1:
            c = vertices[faces[:, 0]]
            lo, hi = c.min(0), c.max(0)
            q = np.floor((c - lo) / np.maximum(hi - lo, 1e-30) * 1023)
            code = _spread_bits(q[:, 0]) | (_spread_bits(q[:, 1]) << 1) | (_spread_bits(q[:, 2]) << 2)
            order = np.argsort(code, kind="stable")
        group = np.empty(len(faces), dtype=np.int64)
        group[order] = np.arange(len(faces)) * clusters // max(1, len(faces))
        n = max(1, len(vertices))
        # each (cluster, vertex) pair once, sorted by cluster
        marks = np.zeros(clusters * n, dtype=bool)
        marks[np.repeat(group, 3) * n + faces.ravel()] = True
        pairs = np.flatnonzero(marks)
        starts = np.searchsorted(pairs // n, np.arange(clusters))
        return TriangleGroups(pairs % n, starts)

    def boxes(self, vertices: np.ndarray) -> Boxes:
        """The clusters' boxes for the mesh's ``vertices`` (n, 3) now."""
        if len(self.vertex_index) == 0:
            return Boxes.empty()
        p = np.asarray(vertices, dtype=np.float64).reshape(-1, 3)[self.vertex_index]
        return Boxes(np.minimum.reduceat(p, self.starts, axis=0),
                     np.maximum.reduceat(p, self.starts, axis=0))


def triangle_cluster_boxes(vertices: np.ndarray, faces: np.ndarray, clusters: int) -> Boxes:
    """Boxes of ``clusters`` groups of triangles (:class:`TriangleGroups`)."""
    return TriangleGroups.of(vertices, faces, clusters).boxes(vertices)


def mesh_arrays(shape):
    """(vertices (n, 3), faces (m, 3)) of a mesh shape as NumPy, or None."""
    p = mi.traverse(shape)
    if "vertex_positions" not in p or "faces" not in p:
        return None
    return (np.array(p["vertex_positions"], dtype=np.float64).reshape(-1, 3),
            np.array(p["faces"], dtype=np.int64).reshape(-1, 3))


def shape_boxes(shape, clusters: int = 1, groups: TriangleGroups | None = None) -> Boxes:
    """Boxes covering a Mitsuba shape as it is now: clusters of a mesh's
    triangles (``groups``, or a grouping made now), the bounding box of
    other shapes (or when ``clusters`` is 1)."""
    mesh = mesh_arrays(shape) if clusters > 1 or groups is not None else None
    if mesh is not None:
        groups = groups or TriangleGroups.of(mesh[0], mesh[1], clusters)
        return groups.boxes(mesh[0])
    bb = shape.bbox()
    return Boxes(np.array(bb.min, dtype=np.float64)[None], np.array(bb.max, dtype=np.float64)[None])


def occluders(params):
    """Every shape of the scene that can block light (all but the medium
    boundary, which exact visibility passes)."""
    med = params.medium.medium
    return [s for s in params.scene.shapes()
            if not (s.interior_medium() is not None and med is not None
                    and s.interior_medium().ptr == med.ptr)]


# -- the extruded volumes as planes ------------------------------------------------
def light_anchor(light):
    """('directional', l toward the light) or ('point', light position)."""
    if light.kind == "directional":
        return "directional", np.asarray(light.direction, dtype=np.float64)
    return "point", np.asarray(light.position, dtype=np.float64)


def shadow_volume_planes(boxes: Boxes, light) -> np.ndarray:
    """(n, PLANES_PER_VOLUME, 4) half-spaces ``n·x <= c`` (unit ``n``) whose
    intersection is each box's shadow volume (module doc): slots 0–5 the
    box faces facing the light, slots 6–17 the supporting planes through
    its edges and the light (directional: containing ``l``).  Unused slots
    are ``0·x <= 1``; a box holding a point light has only unused slots (its
    volume is everything)."""
    kind, a = light_anchor(light)
    n = len(boxes)
    out = np.zeros((n, PLANES_PER_VOLUME, 4))
    out[:, :, 3] = 1.0
    if n == 0:
        return out
    lo, hi = boxes.lo, boxes.hi
    normals = np.array([[-1, 0, 0], [1, 0, 0], [0, -1, 0], [0, 1, 0], [0, 0, -1], [0, 0, 1]],
                       dtype=np.float64)
    c = np.where(normals[None] > 0, hi[:, None], lo[:, None])          # (n, 6, 3) a face point
    c = np.einsum("fk,nfk->nf", normals, c)
    facing = (normals @ a)[None] >= 0 if kind == "directional" else (normals @ a)[None] >= c
    out[:, :6, :3] = np.where(facing[..., None], normals[None], 0.0)
    out[:, :6, 3] = np.where(facing, c, 1.0)
    bits = (np.arange(8)[:, None] >> np.arange(3)[None]) & 1
    corners = np.where(bits[None] == 1, hi[:, None], lo[:, None])       # (n, 8, 3)
    ia, ib = np.array(_EDGES).T
    pa, pb = corners[:, ia], corners[:, ib]                             # (n, 12, 3)
    arm = np.broadcast_to(a, pa.shape) if kind == "directional" else a - pa
    m = np.cross(pb - pa, arm)
    norm = np.linalg.norm(m, axis=2)
    ok = norm > 1e-12 * np.linalg.norm(pb - pa, axis=2) * np.linalg.norm(arm, axis=2)
    m = m / np.where(ok, norm, 1.0)[..., None]
    side = np.einsum("nek,njk->nej", m, corners) - np.einsum("nek,nek->ne", m, pa)[..., None]
    tol = 1e-9 * np.max(hi - lo, axis=1)[:, None, None]
    below, above = np.all(side <= tol, axis=2), np.all(side >= -tol, axis=2)
    sign = np.where(below, 1.0, -1.0)
    use = ok & (below | above)   # an edge pointing at the light: its faces bound the volume
    out[:, 6:, :3] = np.where(use[..., None], sign[..., None] * m, 0.0)
    out[:, 6:, 3] = np.where(use, sign * np.einsum("nek,nek->ne", m, pa), 1.0)
    if kind == "point":
        inside = np.all((a >= lo) & (a <= hi), axis=1)
        out[inside, :, :3], out[inside, :, 3] = 0.0, 1.0
    return out


@dataclass(frozen=True)
class ShadowVolumes:
    """Plane arrays of ``count`` volumes on the Dr.Jit device, ready for
    :func:`clip_segments`: the used planes of volume ``v`` (unused slots of
    :func:`shadow_volume_planes` dropped; one kept where none is used) are
    ``start[v] .. start[v + 1] - 1`` of ``nx, ny, nz, c``; ``plane_volume``
    names each plane's volume.  Volume ``v`` is a *leaf* (its pieces
    count) or the *hull* of the leaves that follow it (a segment missing
    it skips to volume ``skip[v]``)."""
    count: int
    nx: mi.Float
    ny: mi.Float
    nz: mi.Float
    c: mi.Float
    skip: mi.UInt32
    leaf: mi.Bool
    start: mi.UInt32 | None = None
    plane_volume: mi.UInt32 | None = None
    #: (lo, hi) NumPy: an axis-aligned box holding every volume inside the
    #: medium box (:func:`volume_bounds`; segments are camera segments, which
    #: lie in it); None: unknown (no medium given)
    bounds: tuple | None = None

    @staticmethod
    def from_boxes(boxes: Boxes, params, pad: float = PAD) -> "ShadowVolumes":
        """One leaf volume per box."""
        return ShadowVolumes.from_sets([Boxes(boxes.lo[i:i + 1], boxes.hi[i:i + 1])
                                        for i in range(len(boxes))], params, pad)

    @staticmethod
    def from_sets(sets, params, pad: float = PAD) -> "ShadowVolumes":
        """Volumes of the boxes of each set (e.g. the clusters of one mesh),
        a set of several boxes preceded by the hull of its boxes, so that
        segments far from an object test one volume instead of all."""
        lo, hi, skip, leaf = [], [], [], []
        for b in (b for b in sets if len(b)):
            if len(b) > 1:
                lo.append(b.lo.min(0, keepdims=True))
                hi.append(b.hi.max(0, keepdims=True))
                skip.append(len(skip) + 1 + len(b))
                leaf.append(False)
            lo.append(b.lo)
            hi.append(b.hi)
            skip += list(range(len(skip) + 1, len(skip) + 1 + len(b)))
            leaf += [True] * len(b)
        boxes = Boxes(np.concatenate(lo), np.concatenate(hi)) if lo else Boxes.empty()
        planes = shadow_volume_planes(boxes.padded(pad * params.scene_extent), params.light)
        used = np.any(planes[..., :3] != 0.0, axis=2)
        used[~used.any(axis=1), 0] = True           # everything: one plane that never cuts
        counts = used.sum(axis=1)
        start = np.concatenate([[0], np.cumsum(counts)]).astype(np.uint32)
        flat = planes[used].astype(np.float32)      # volume by volume, slot order
        return ShadowVolumes(len(boxes), *(mi.Float(np.ascontiguousarray(flat[:, k]))
                                           for k in range(4)),
                             mi.UInt32(np.array(skip, dtype=np.uint32)),
                             mi.Bool(np.array(leaf, dtype=bool)), mi.UInt32(start),
                             mi.UInt32(np.repeat(np.arange(len(boxes), dtype=np.uint32), counts)),
                             volume_bounds(boxes.padded(2 * pad * params.scene_extent), params)
                             if len(boxes) and getattr(params, "medium", None) else None)


def volume_bounds(boxes: Boxes, params) -> tuple:
    """(lo, hi): an axis-aligned box holding the shadow volumes of ``boxes``
    inside the medium box.  Per axis, a volume runs from its box to the
    medium's face the extrusion moves toward: directional light toward
    ``l``: the face on the side of −l (the box's own extent where l_a = 0);
    point/spot light at ``p``: the far face where the box lies wholly on
    one side of ``p``, the whole medium extent otherwise."""
    m_lo = np.asarray(params.medium.bounds_min, np.float64)
    m_hi = np.asarray(params.medium.bounds_max, np.float64)
    kind, a = light_anchor(params.light)
    lo, hi = boxes.lo.copy(), boxes.hi.copy()
    if kind == "directional":
        lo = np.where(a[None] > 0, np.minimum(lo, m_lo[None]), lo)
        hi = np.where(a[None] < 0, np.maximum(hi, m_hi[None]), hi)
    else:
        lo = np.where(boxes.lo > a[None], lo, np.minimum(lo, m_lo[None]))
        hi = np.where(boxes.hi < a[None], hi, np.maximum(hi, m_hi[None]))
    return lo.min(0), hi.max(0)


#: clip only the segments meeting the volumes' bounds when fewer than this
#: fraction of them do (else all: the compaction would cost more than it saves)
CULL_FRACTION = 0.6


def clip_segments(volumes: ShadowVolumes, o, omega, d, first_hit: bool = False):
    """:func:`clip_volumes` of the segments that meet ``volumes.bounds``
    alone (the others meet no volume: ``hit`` False, ``t_lo > t_hi``)."""
    n = dr.width(d)
    if volumes.count == 0 or volumes.bounds is None:
        return clip_volumes(volumes, o, omega, d, first_hit)
    t0, t1 = slabs(o, omega, volumes.bounds[0], volumes.bounds[1])
    near = (t1 >= dr.maximum(t0, 0.0)) & (t0 <= d)
    idx = dr.compress(near)
    m = dr.width(idx)
    if m > CULL_FRACTION * n:
        return clip_volumes(volumes, o, omega, d, first_hit)
    hit, lo, hi = (dr.zeros(mi.Bool, n), dr.full(mi.Float, dr.inf, n),
                   dr.full(mi.Float, -dr.inf, n))
    if m:
        h, l, u = clip_volumes(volumes, dr.gather(type(o), o, idx),
                               dr.gather(type(omega), omega, idx),
                               dr.gather(mi.Float, mi.Float(d), idx), first_hit)
        dr.scatter(hit, h, idx)
        dr.scatter(lo, l, idx)
        dr.scatter(hi, u, idx)
    return hit, lo, hi


def clip_volumes(volumes: ShadowVolumes, o, omega, d, first_hit: bool = False):
    """Cyrus–Beck clipping of the segments ``o + t·ω``, ``t ∈ [0, d]``
    against every leaf volume (hulls only prune).  Returns ``(hit, t_lo,
    t_hi)``: whether any leaf meets the segment and the hull ``[t_lo,
    t_hi]`` of the pieces inside (``t_lo > t_hi`` where none; with
    ``first_hit`` a segment stops at its first leaf hit, so only ``hit`` is
    complete).  One kernel whatever the volume count; a segment leaves a
    volume at the first plane that empties its interval."""
    n = dr.width(d)
    d = mi.Float(d)
    if volumes.count == 0:
        return dr.zeros(mi.Bool, n), dr.full(mi.Float, dr.inf, n), dr.full(mi.Float, -dr.inf, n)
    total = opaque_scalar(mi.UInt32, dr.width(volumes.c))

    def body(j, t0, t1, lo, hi):
        v = dr.gather(mi.UInt32, volumes.plane_volume, j)
        begin = dr.gather(mi.UInt32, volumes.start, v)
        end = dr.gather(mi.UInt32, volumes.start, v + 1)
        nv = mi.Vector3f(dr.gather(mi.Float, volumes.nx, j), dr.gather(mi.Float, volumes.ny, j),
                         dr.gather(mi.Float, volumes.nz, j))
        c = dr.gather(mi.Float, volumes.c, j)
        first = j == begin
        t0 = dr.select(first, 0.0, t0)
        t1 = dr.select(first, d, t1)
        den = dr.dot(nv, omega)
        num = c - dr.dot(nv, mi.Vector3f(o))
        t = num / dr.select(den == 0, 1.0, den)
        t1 = dr.select(den > 0, dr.minimum(t1, t), t1)
        t0 = dr.select(den < 0, dr.maximum(t0, t), t0)
        t1 = dr.select((den == 0) & (num < 0), -1.0, t1)
        empty = t0 > t1
        done = (j + 1 == end) | empty
        leaf = dr.gather(mi.Bool, volumes.leaf, v, done)
        meets = done & ~empty
        inside = meets & leaf
        lo = dr.select(inside, dr.minimum(lo, t0), lo)
        hi = dr.select(inside, dr.maximum(hi, t1), hi)
        skip_to = dr.gather(mi.UInt32, volumes.start,
                            dr.gather(mi.UInt32, volumes.skip, v, done & ~leaf), done & ~leaf)
        nxt = dr.select(done, dr.select(empty & ~leaf, skip_to, end), j + 1)
        if first_hit:
            nxt = dr.select(inside, total, nxt)
        return nxt, t0, t1, lo, hi

    _, _, _, lo, hi = dr.while_loop(
        state=(mi.UInt32(0), dr.zeros(mi.Float, n), mi.Float(d),
               dr.full(mi.Float, dr.inf, n), dr.full(mi.Float, -dr.inf, n)),
        cond=lambda j, *_: j < total, body=body)
    return lo <= hi, lo, hi


# -- the NumPy oracle ----------------------------------------------------------------
def in_shadow_volume_reference(x: np.ndarray, boxes: Boxes, light) -> np.ndarray:
    """Per point of ``x`` (n, 3): does its light ray (toward a directional
    light, or the segment to a point/spot light) meet one of ``boxes``?
    Slab test in float64."""
    kind, a = light_anchor(light)
    x = np.asarray(x, dtype=np.float64)
    w = np.broadcast_to(a, x.shape) if kind == "directional" else a - x
    s_max = np.inf if kind == "directional" else 1.0
    out = np.zeros(len(x), dtype=bool)
    with np.errstate(divide="ignore", invalid="ignore"):
        for lo, hi in zip(boxes.lo, boxes.hi):
            t0, t1 = (lo - x) / w, (hi - x) / w
            near = np.nanmax(np.where(w == 0, np.where((x >= lo) & (x <= hi), -np.inf, np.inf),
                                      np.minimum(t0, t1)), axis=1)
            far = np.nanmin(np.where(w == 0, np.where((x >= lo) & (x <= hi), np.inf, -np.inf),
                                     np.maximum(t0, t1)), axis=1)
            out |= np.maximum(near, 0.0) <= np.minimum(far, s_max)
    return out

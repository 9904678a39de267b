"""Captures: the ray-traced inputs every method starts from (DESIGN §3).

* :func:`capture_camera` — the camera G-buffer per camera sample: ray origin
  and direction (Mitsuba's own ``sensor.sample_ray``), ``d`` = distance to the
  first non-null surface or to the medium exit, and the surface term for
  ``output="full"``: direct lighting of the visible surface with ray-traced
  visibility and light-side transmittance (what ``volpath`` ``max_depth=2``
  adds to single scattering), plus the camera-side transmittance
  ``T_cam = e^{-σt·(in-medium length)}`` that attenuates it.
* :func:`capture_shadow_map` — a light-space shadow map by ray casting:
  orthographic for directional lights (fitted to what the camera sees inside
  the medium), perspective for spot lights, a cube of six faces for point
  lights (and for spot lights wider than 60°).  ``ShadowMap.visibility(x)``
  answers V(x) with 2×2 percentage-closer filtering.
"""
from __future__ import annotations

from dataclasses import dataclass, field, replace

import drjit as dr
import mitsuba as mi
import numpy as np

from .light_transport import (as_color3, color, first_blocker, light_transmittance,
                              medium_exit_distance, medium_interval, point, scalar, segment_box,
                              vector, visible_exact)
from .opaque import floats, reciprocal


#: null-BSDF surfaces a camera or light ray may pass before we give up.
MAX_NULL_CROSSINGS = 4


def first_surface(scene, ray, active=True):
    """First intersection with a non-null surface along ``ray`` (null-BSDF
    surfaces such as the medium box are passed, at most
    :data:`MAX_NULL_CROSSINGS` of them, in a symbolic loop: no kernel and no
    host read of its own).  Returns (si, t) with ``t`` measured from the
    original ray origin; ``si.is_valid()`` is False if the ray escapes."""
    active = mi.Bool(active)
    origin, direction = mi.Point3f(ray.o), mi.Vector3f(ray.d)
    si = scene.ray_intersect(ray, active)

    def passing(i, si, ray):
        return ((i < MAX_NULL_CROSSINGS) & active & si.is_valid()
                & mi.has_flag(si.bsdf(ray).flags(), mi.BSDFFlags.Null))

    def cross(i, si, ray):
        # continue along the ray itself (spawn_ray would offset the origin
        # along the surface normal, shifting the ray sideways by ~mm)
        off = 16 * mi.math.RayEpsilon * (1 + dr.max(dr.abs(si.p)))
        nxt = mi.Ray3f(si.p + ray.d * off, ray.d)
        return i + 1, scene.ray_intersect(nxt), nxt

    _, si, _ = dr.while_loop((mi.UInt32(0), si, mi.Ray3f(ray)), passing, cross,
                             label="first_surface")
    # distance from the original origin (spawned rays start slightly offset)
    t = dr.dot(mi.Vector3f(si.p - origin), direction) * dr.rcp(dr.squared_norm(direction))
    return si, dr.select(si.is_valid(), t, dr.inf)


def seed_offset(seed: int, salt: int) -> int:
    """A 64-bit PCG32 state offset for ``seed`` (wrapped, never overflowing)."""
    return (salt * (int(seed) + 1)) & 0xFFFFFFFFFFFFFFFF


#: PCG32's default sequence (increment) constant
PCG32_DEFAULT_STREAM = 0xDA3E39CB94B95BDB


def sample_rng(index: mi.UInt32, state: int) -> mi.PCG32:
    """One PCG32 per camera sample, keyed by its ``index`` in the full
    capture: the generator ``mi.PCG32(size=n, initstate=arange(n) + state)``
    gives sample ``index`` (that constructor adds ``arange`` to the state and
    the sequence), so a partial render draws the full render's numbers."""
    i = mi.UInt64(index)
    rng = mi.PCG32(size=dr.width(i))
    rng.seed(initstate=i + i + mi.UInt64(state), initseq=mi.UInt64(PCG32_DEFAULT_STREAM) + i)
    return rng


def _camera_positions(width, height, spp, jitter, seed, samples=None):
    """Film positions (in [0,1]^2) and pixel indices of spp samples per pixel:
    stratified on a k x k grid when spp = k², else independent; jittered
    inside each cell or at its centre.  ``samples``: the sample indices
    (default all, ``pixel·spp + k``); a sample's position depends on its
    index alone."""
    idx = dr.arange(mi.UInt32, width * height * spp) if samples is None else mi.UInt32(samples)
    pixel = idx // spp
    px = mi.Float(pixel % width)
    py = mi.Float(pixel // width)
    if jitter:
        # seeded by the sample index alone (PCG32(size=...) would add the
        # position in the array to both state and stream): the full capture's
        # numbers for any subset of samples
        rng = sample_rng(idx, seed_offset(seed, 0x9E3779B97F4A7C15))
        ox, oy = rng.next_float32(), rng.next_float32()
    else:
        ox = oy = mi.Float(0.5)
    k = int(round(spp ** 0.5))
    if k > 1 and k * k == spp:
        # stratified: one sample per cell of a k x k grid inside the pixel
        cell = idx % spp
        ox = (mi.Float(cell % k) + ox) / k
        oy = (mi.Float(cell // k) + oy) / k
    return mi.Point2f((px + ox) / width, (py + oy) / height), pixel


@dataclass
class CameraCapture:
    """G-buffer per camera sample (``spp`` consecutive samples per pixel)."""
    width: int
    height: int
    spp: int
    pixel: mi.UInt32
    o: mi.Point3f           # ray origin (on the near plane, as Mitsuba)
    omega: mi.Vector3f      # unit direction
    d: mi.Float             # where the scattering range ends (surface or medium exit)
    T_cam: mi.Color3f       # e^{-σt (d - t_in)}
    L_surface: mi.Color3f   # lit surface radiance at the hit, before T_cam
    hit: mi.Bool            # the ray meets a non-null surface
    #: index of each sample in the full capture (pixel*spp + k); None: all of
    #: them in order (a full capture)
    sample: mi.UInt32 | None = None
    #: the full capture this one is a subset of (None: this is the full one)
    parent: "CameraCapture | None" = None
    #: camera outside the medium: where each ray enters it (the scattering
    #: range is [t_in, d]; inf for a ray that misses it); None: the camera is
    #: inside (t_in = 0)
    t_in: mi.Float | None = None

    def entered(self) -> "CameraCapture":
        """The same samples with each ray starting where it enters the
        medium: origin ``o + t_in·ω``, range ``max(d - t_in, 0)`` (``self``
        when the camera is inside).  A per-sample method integrating over
        ``[0, d]`` from ``o`` integrates the medium part of the view ray."""
        if self.t_in is None:
            return self
        t = dr.minimum(self.t_in, self.d)
        return replace(self, o=self.o + self.omega * t, d=self.d - t, t_in=None)

    def endpoints(self) -> mi.Point3f:
        return self.o + self.omega * self.d

    @property
    def count(self) -> int:
        """Number of camera samples held."""
        return dr.width(self.d)

    def whole(self) -> "CameraCapture":
        """The full capture (``self`` unless this is a subset): frame-wide
        choices (a shadow map's fit) are made on it, so that a partial render
        computes its samples exactly as the full render does."""
        return self if self.parent is None else self.parent

    def sample_index(self) -> mi.UInt32:
        """Index of each held sample in the full capture's order."""
        return dr.arange(mi.UInt32, self.count) if self.sample is None else self.sample

    def subset(self, index: mi.UInt32) -> "CameraCapture":
        """The samples at positions ``index`` of this capture (a partial
        render's capture: the same rays, a subset of them)."""
        def take(v):
            return dr.gather(type(v), v, index)
        return CameraCapture(width=self.width, height=self.height, spp=self.spp,
                             pixel=take(self.pixel), o=take(self.o), omega=take(self.omega),
                             d=take(self.d), T_cam=take(self.T_cam),
                             L_surface=take(self.L_surface), hit=take(self.hit),
                             sample=take(self.sample_index()), parent=self.whole(),
                             t_in=None if self.t_in is None else take(self.t_in))


def capture_camera(params, spp=1, jitter=False, seed=0, surface=True,
                   samples=None) -> CameraCapture:
    """The G-buffer of every camera sample, or of the sample indices
    ``samples`` alone (each with the values it has in the full capture)."""
    cam, scene, sensor = params.camera, params.scene, params.sensor
    pos, pixel = _camera_positions(cam.width, cam.height, spp, jitter, seed, samples)
    ray, _ = sensor.sample_ray(0.0, 0.5, pos, mi.Point2f(0.5, 0.5))
    ray.d = dr.normalize(ray.d)
    si, t_surf = first_surface(scene, ray)
    t_in = None
    if params.camera_outside:
        # the view ray's medium part: from its entry to the surface or the exit
        t_near, t_far = medium_interval(params, ray.o, ray.d)
        t_in = dr.select(t_far >= dr.maximum(t_near, 0.0), dr.maximum(t_near, 0.0), dr.inf)
        d = dr.minimum(t_surf, dr.maximum(t_far, 0.0))
        T_cam = dr.exp(-color(params.medium.sigma_t) * dr.maximum(d - t_in, 0.0))
    else:
        t_exit = medium_exit_distance(params, ray.o, ray.d)
        d = dr.minimum(t_surf, t_exit)
        T_cam = dr.exp(-color(params.medium.sigma_t) * d)
    L_surface = dr.zeros(mi.Color3f, dr.width(d))
    if surface:     # the sum over the lights (linear in the light)
        lights = params.per_light()
        L_surface = surface_direct_lighting(lights[0], si, ray)
        for one in lights[1:]:
            L_surface += surface_direct_lighting(one, si, ray)
    cap = CameraCapture(width=cam.width, height=cam.height, spp=spp, pixel=pixel,
                        o=ray.o, omega=ray.d, d=d, T_cam=T_cam, L_surface=L_surface,
                        hit=si.is_valid(),
                        sample=None if samples is None else mi.UInt32(samples), t_in=t_in)
    dr.eval(cap.o, cap.omega, cap.d, cap.T_cam, cap.L_surface, cap.hit,
            *(() if t_in is None else (t_in,)))
    return cap


def surface_direct_lighting(params, si, ray):
    """Direct lighting of the visible surface by ``params``' one light
    (BSDF · light · V · e^{-σt τ})."""
    active = si.is_valid()
    ds, spec = params.light.emitter.sample_direction(si, mi.Point2f(0.5, 0.5), active)
    wo = ds.d
    dist = ds.dist if params.light.kind != "directional" else dr.full(mi.Float, dr.inf, dr.width(ds.d))
    x = si.spawn_ray(wo).o
    tau, t_in, t_out = segment_box(params, x, wo, dist)
    vis = visible_exact(params, x, wo, dist, t_in, t_out, active)
    bsdf = si.bsdf(ray)
    f = bsdf.eval(mi.BSDFContext(), si, si.to_local(wo), active)
    L = as_color3(f) * as_color3(spec) * light_transmittance(params, tau)
    return dr.select(active & vis, L, 0.0)


# ---------------------------------------------------------------------------
@dataclass
class ShadowMap:
    """Depths of the first blocker along a grid of light rays.

    ``kind``: 'ortho' (directional), 'persp' (spot) or 'cube' (point).  Depth
    is measured along each light ray: from the light-space plane ``s0`` for
    'ortho', from the light position (radial distance) otherwise."""
    kind: str
    res: int
    depth: mi.Float = field(repr=False)
    frames: list = field(default_factory=list)   # [(right, up, fwd)] numpy (3,)
    tan_half: float = 1.0
    origin: np.ndarray | None = None              # light position (persp/cube)
    u0: float = 0.0
    v0: float = 0.0
    du: float = 1.0
    dv: float = 1.0
    s0: float = 0.0
    bias: float = 0.0

    @property
    def texels(self) -> int:
        return self.res * self.res * len(self.frames)

    # -- light ray of every texel -------------------------------------------
    def texel_rays(self):
        res = self.res
        idx = dr.arange(mi.UInt32, self.texels)
        face = idx // (res * res)
        j = mi.Float((idx // res) % res)
        i = mi.Float(idx % res)
        if self.kind == "ortho":
            e1, e2, w = (vector(v) for v in self.frames[0])
            u = scalar(self.u0) + (i + 0.5) * scalar(self.du)
            v = scalar(self.v0) + (j + 0.5) * scalar(self.dv)
            o = e1 * u + e2 * v + w * scalar(self.s0)
            return mi.Point3f(o), -w
        tan_half = scalar(self.tan_half)
        a = ((i + 0.5) / res * 2 - 1) * tan_half
        b = ((j + 0.5) / res * 2 - 1) * tan_half
        right, up, fwd = (self._gather_frame(face, k) for k in range(3))
        d = dr.normalize(fwd + right * a + up * b)
        return point(self.origin), d

    def _gather_frame(self, face, k):
        arr = np.array([f[k] for f in self.frames], dtype=np.float32)  # (faces, 3)
        return mi.Vector3f(*(dr.gather(mi.Float, floats(arr[:, c]), face) for c in range(3)))

    # -- lookups ----------------------------------------------------------------
    def _coords(self, x):
        """(face, continuous texel coords u, v, depth of x along its light ray)."""
        res = self.res
        if self.kind == "ortho":
            e1, e2, w = (vector(v) for v in self.frames[0])
            xv = mi.Vector3f(x)
            u = (dr.dot(xv, e1) - scalar(self.u0)) * reciprocal(self.du) - 0.5
            v = (dr.dot(xv, e2) - scalar(self.v0)) * reciprocal(self.dv) - 0.5
            return mi.UInt32(0), u, v, scalar(self.s0) - dr.dot(xv, w)
        q = mi.Vector3f(x - point(self.origin))
        if self.kind == "cube":
            aq = dr.abs(q)
            xmax = (aq.x >= aq.y) & (aq.x >= aq.z)
            ymax = ~xmax & (aq.y >= aq.z)
            face = dr.select(xmax, dr.select(q.x > 0, 0, 1),
                             dr.select(ymax, dr.select(q.y > 0, 2, 3), dr.select(q.z > 0, 4, 5)))
            face = mi.UInt32(face)
        else:
            face = mi.UInt32(0)
        right, up, fwd = (self._gather_frame(face, k) for k in range(3))
        z = dr.dot(q, fwd)
        inv = dr.rcp(dr.maximum(z, 1e-20) * scalar(self.tan_half))
        u = (dr.dot(q, right) * inv + 1) * 0.5 * res - 0.5
        v = (dr.dot(q, up) * inv + 1) * 0.5 * res - 0.5
        return face, u, v, dr.norm(q)

    def nearest_depth(self, x) -> mi.Float:
        """Depth of the texel nearest to where ``x`` projects (the paper's
        "rectify the shadow map", Baran §3); +inf where the map records no
        blocker, or outside a perspective map (no information there)."""
        res = self.res
        face, u, v, _ = self._coords(x)
        iu = mi.UInt32(dr.clip(mi.Int32(dr.round(u)), 0, res - 1))
        iv = mi.UInt32(dr.clip(mi.Int32(dr.round(v)), 0, res - 1))
        z_b = dr.gather(mi.Float, self.depth, face * res * res + iv * res + iu)
        if self.kind == "persp":
            inside = (u > -0.5) & (u < res - 0.5) & (v > -0.5) & (v < res - 0.5)
            z_b = dr.select(inside, z_b, dr.inf)
        return z_b

    def visibility(self, x, active=True):
        """V(x) in [0, 1]: 2×2 percentage-closer filtered shadow test."""
        res = self.res
        face, u, v, z = self._coords(x)
        fu, fv = dr.floor(u), dr.floor(v)
        tu, tv = u - fu, v - fv
        iu, iv = mi.Int32(fu), mi.Int32(fv)
        V = mi.Float(0.0)
        for du, dv, wgt in ((0, 0, (1 - tu) * (1 - tv)), (1, 0, tu * (1 - tv)),
                            (0, 1, (1 - tu) * tv), (1, 1, tu * tv)):
            ci = dr.clip(iu + du, 0, res - 1)
            cj = dr.clip(iv + dv, 0, res - 1)
            idx = mi.UInt32(face * res * res + mi.UInt32(cj) * res + mi.UInt32(ci))
            zb = dr.gather(mi.Float, self.depth, idx, active)
            V += dr.select(zb >= z - scalar(self.bias), wgt, 0.0)
        if self.kind == "persp":
            # outside the spot cone: no blocker information; the emitter's own
            # falloff is zero there anyway.
            inside = (u > -0.5) & (u < res - 0.5) & (v > -0.5) & (v < res - 0.5)
            V = dr.select(inside, V, 1.0)
        return V

    def depth_bounds(self, x, active=True):
        """(min, max) blocker depth of the 4×4 texels around ``x``: every
        point within half a texel of ``x`` (on the same face) filters only
        these in :meth:`visibility`, so ``z <= min + bias`` means lit and
        ``z > max + bias`` shadowed for all of them.  Outside a spot map:
        (inf, inf), as :meth:`visibility` counts it lit."""
        res = self.res
        face, u, v, _ = self._coords(x)
        iu, iv = mi.Int32(dr.floor(u)), mi.Int32(dr.floor(v))
        lo = dr.full(mi.Float, dr.inf, dr.width(u))
        hi = dr.full(mi.Float, -dr.inf, dr.width(u))
        for du in range(-1, 3):
            for dv in range(-1, 3):
                ci = dr.clip(iu + du, 0, res - 1)
                cj = dr.clip(iv + dv, 0, res - 1)
                idx = mi.UInt32(face * res * res + mi.UInt32(cj) * res + mi.UInt32(ci))
                zb = dr.gather(mi.Float, self.depth, idx, active)
                lo, hi = dr.minimum(lo, zb), dr.maximum(hi, zb)
        if self.kind == "persp":
            inside = (u > -1.5) & (u < res + 0.5) & (v > -1.5) & (v < res + 0.5)
            lo = dr.select(inside, lo, dr.inf)
            hi = dr.select(inside, hi, dr.inf)
        return lo, hi


def _orthonormal(w):
    w = np.asarray(w, dtype=np.float64)
    w = w / np.linalg.norm(w)
    a = np.array([1.0, 0, 0]) if abs(w[0]) < 0.9 else np.array([0, 1.0, 0])
    e1 = np.cross(w, a)
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(w, e1)
    return e1, e2, w


CUBE_FACES = [  # (right, up, fwd) per face: +x, -x, +y, -y, +z, -z
    ((0, 0, -1), (0, -1, 0), (1, 0, 0)), ((0, 0, 1), (0, -1, 0), (-1, 0, 0)),
    ((1, 0, 0), (0, 0, 1), (0, 1, 0)), ((1, 0, 0), (0, 0, -1), (0, -1, 0)),
    ((1, 0, 0), (0, -1, 0), (0, 0, 1)), ((-1, 0, 0), (0, -1, 0), (0, 0, -1)),
]


def capture_shadow_map(params, camera_capture: CameraCapture, res: int) -> ShadowMap:
    """Trace a shadow map of ``res``×``res`` texels (per face)."""
    light = params.light
    extent = params.scene_extent
    if light.kind == "directional":
        e1, e2, w = _orthonormal(light.direction)
        pts = camera_capture.whole().endpoints()
        u = dr.dot(mi.Vector3f(pts), vector(e1))
        v = dr.dot(mi.Vector3f(pts), vector(e2))
        o = params.camera.origin
        dr.eval(u, v)                   # one kernel; the four reductions read it
        u_lo = min(float(dr.min(u)[0]), float(o @ e1))
        u_hi = max(float(dr.max(u)[0]), float(o @ e1))
        v_lo = min(float(dr.min(v)[0]), float(o @ e2))
        v_hi = max(float(dr.max(v)[0]), float(o @ e2))
        pad_u = (u_hi - u_lo) / res + 1e-6 * extent
        pad_v = (v_hi - v_lo) / res + 1e-6 * extent
        u_lo, u_hi, v_lo, v_hi = u_lo - pad_u, u_hi + pad_u, v_lo - pad_v, v_hi + pad_v
        bb = params.scene.bbox()
        corners = np.array([[x, y, z] for x in (bb.min[0], bb.max[0])
                            for y in (bb.min[1], bb.max[1]) for z in (bb.min[2], bb.max[2])])
        s0 = float(np.max(corners @ w)) + 1e-3 * extent
        sm = ShadowMap(kind="ortho", res=res, depth=mi.Float(0), frames=[(e1, e2, w)],
                       u0=u_lo, v0=v_lo, du=(u_hi - u_lo) / res, dv=(v_hi - v_lo) / res,
                       s0=s0)
    elif light.kind == "spot" and light.cutoff_angle <= 60:
        right, up, fwd = _orthonormal(light.spot_axis)
        sm = ShadowMap(kind="persp", res=res, depth=mi.Float(0), frames=[(right, up, fwd)],
                       tan_half=float(np.tan(np.radians(light.cutoff_angle))) * (1 + 2.0 / res),
                       origin=np.asarray(light.position))
    else:
        frames = [tuple(np.array(a, dtype=np.float64) for a in f) for f in CUBE_FACES]
        sm = ShadowMap(kind="cube", res=res, depth=mi.Float(0), frames=frames,
                       tan_half=1.0, origin=np.asarray(light.position))
    o, d = sm.texel_rays()
    # the occluders exact visibility sees (the medium box excepted), with
    # preliminary intersections only: a depth is all a texel keeps
    o, d = mi.Point3f(o), mi.Vector3f(d)
    hit, p = first_blocker(params, o, d)
    t = dr.dot(mi.Vector3f(p - o), d) * dr.rcp(dr.squared_norm(d))
    sm.depth = dr.select(hit, t, dr.inf)
    sm.bias = 1e-4 * extent
    dr.eval(sm.depth)
    return sm

"""Blocker maps traced along the epipolar light rays against blocker maps
resampled from a classic shadow map (rectify issue, point 2).

``epipolar_tree`` builds its blocker map S[α, γ] either by ray-tracing every
light ray of every slice with Mitsuba (``rectification="traced"``,
:func:`~integrators.epipolar.blockers.trace_blocker_angles`,
:func:`~integrators.epipolar.local_blockers.trace_local_blocker_angles`) or, as
Baran et al. 2010 §3 do, by reading the blocker depth of each light ray from
a square shadow map, nearest texel (``"resampled"``,
:func:`~integrators.epipolar.blockers.shadow_map_blocker_angles`, both light
kinds).
Here both are built on suite scenes at 64x48 as ``epipolar_tree`` builds
them (sinh slices, 2° ring, the automatic ``d`` = 80 light rays per slice),
with one sub-ray through each light ray's centre (``prefilter=1``), and
compared:

- ``status``: fraction of the (lit) light rays blocked in one map and not in
  the other;
- ``β error``: |β_traced − β_resampled| of the light rays blocked in both;
- ``index``: fraction of light rays whose blocker lands on a different view
  ray of the sweep (:func:`~integrators.epipolar.blockers.blocker_modes`: the
  number of the slice's queries with β_q ≤ S), i.e. that shadow a different
  set of pixels;
- ``flips``: fraction of the visibility samples the sweep actually uses
  (query q, light ray g in front of q's end point, g + ½ < D_q) whose
  lit/shadowed value differs -- what reaches the image.

"Up to the resampling error" is checked exactly: the resampled angle of
every light ray must be the angle of the blocker found by tracing, with the
map's own tracer, the line through the centre of the texel it reads, the
map's depth bias (1e-4 of the scene extent) applied (``explained``: measured
β difference < 5e-4°, no status, index or flip difference, on every scene
and map size) -- so all of the disagreement below is where the light ray is
sampled.  Every disagreement measure then shrinks as the map grows.

How much that is (measured, 64x48, d = 80 light rays per slice, angles in
degrees; ``*`` = the fast test's pair, the others the ``slow`` test's):

==============  =====  =======  ======  =====  =====  ======  ======
scene (rays)    map    status   β p50   β p90  β p99  index   flips
==============  =====  =======  ======  =====  =====  ======  ======
nave_offscreen  256*   0        0.054   0.17   2.2    3.0 %   1.4 %
(7040)          512    0        0.026   0.085  0.59   1.6 %   0.66 %
                1024*  0        0.014   0.047  0.25   0.78 %  0.35 %
                2048   0        0.0096  0.031  0.18   0.60 %  0.072 %
nave_onscreen   256*   0        0.023   0.16   1.7    1.9 %   0.96 %
(15360)         512    0        0.012   0.080  0.58   0.85 %  0.40 %
                1024*  0        0.0067  0.046  0.33   0.55 %  0.23 %
                2048   0        0.0054  0.035  0.22   0.36 %  0.16 %
grove           256*   0.041 %  0.13    3.1    92     17 %    8.4 %
(7360)          512    0.014 %  0.059   1.4    65     11 %    4.8 %
                1024*  0.014 %  0.033   0.61   53     7.3 %   3.5 %
                2048   0        0.025   0.17   32     4.6 %   2.3 %
spot_room       256*   0        0.043   0.15   0.30   2.7 %   0.12 %
(1804 lit)      512    0        0.024   0.080  0.16   1.3 %   0.011 %
                1024*  0        0.017   0.047  0.097  1.0 %   0.013 %
                2048   0        0.015   0.031  0.056  0.78 %  0.033 %
point_fog       256*   0        0.023   0.19   0.75   1.4 %   0.32 %
(13323 lit)     512    0        0.015   0.098  0.37   0.74 %  0.16 %
                1024*  0        0.013   0.056  0.21   0.43 %  0.028 %
                2048   0        0.013   0.043  0.14   0.40 %  0.047 %
==============  =====  =======  ======  =====  =====  ======  ======

What the numbers say:

- The suite's scenes are closed, so every light ray ends on some surface:
  the blocked/unblocked status almost never differs (grove: 3, 1, 1, 0 of
  7360 light rays).  The meaningful difference is the blocker's β.
- The typical β error (p50, p90) halves with each doubling of the map
  until a floor of ~0.01° set by the map's depth bias: with the bias set
  to 0, point_fog's p50 at 2048² drops from 0.013° to 0.0024°, spot_room's
  from 0.015° to 0.0053°.  The bias also explains the few flips that do
  not shrink at the floor (spot_room, point_fog 1024² -> 2048²): it moves
  blockers next to the queries' own end surfaces.
- The tail does not vanish: light rays within a texel of a silhouette (as
  seen from the light) read the depth of the other surface, an O(1) β error
  on an O(texel) fraction of the light rays.  In the grove's foliage that
  is 4.6 % of the light rays shading a different set of pixels (index) and
  2.3 % of the visibility samples the sweep uses (flips) even at 2048²,
  shrinking only like ~texel^0.6; elsewhere it is 0.05-0.2 % at 2048².
  ``traced`` has none of this.
- Aside (why ``explained`` uses the map's tracer): tracing the same
  texel-centre lines with :func:`~integrators.core.light_transport.first_blocker`
  instead gives a different first leaf on 1.4 % of the grove's light rays at
  1024², because :func:`~integrators.core.capture.first_surface` re-spawns the
  map's rays where they enter the null medium box, offset ~2.4 mm along the
  box normal (~1.8 mm sideways; the grove's box reaches 52 m): a shift far
  below the texel (5 cm at 1024²), but visible in dense foliage.

Fast test (256², 1024²): ~7 s; slow test (512², 2048²): ~19 s (2 cores, load ~9).
"""
from __future__ import annotations

import functools
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

import scenes
from episcatter.scene_loading import load_scene
from integrators.epipolar.light_rays import local as ell_local
from integrators.epipolar import local_blockers as ell_local_blockers
from integrators.epipolar import local_light_factor as ell_local_light_factor
from integrators.epipolar import blockers as es_blockers
from integrators.epipolar import frame as es_frame
from integrators.epipolar.light_rays import directional as es_directional
from integrators.epipolar.light_rays import layout as es_layout
from integrators.epipolar import queries as es_queries
from integrators.core.capture import capture_camera, capture_shadow_map, first_surface
from integrators.epipolar.light_models import light_model
from integrators.core.light_transport import point
from integrators.core.scene_params import SceneParams
from rectify.coords import light_coords_to_world

RES = {"res_x": 64, "res_y": 48}
RING_DEG = 2.0
DIRECTIONAL = ("nave_offscreen", "nave_onscreen", "grove")
LOCAL = ("spot_room", "point_fog")
FAST_MAPS = (256, 1024)
SLOW_MAPS = (512, 2048)


# --------------------------------------------------------------------------
# The maps, as epipolar_tree builds them
# --------------------------------------------------------------------------

@functools.lru_cache(maxsize=None)
def setup(name: str):
    """(params, cap, queries, rays, lit, traced β) of a suite scene at 64x48:
    epipolar_tree's rectification with the automatic slices and light rays,
    one sub-ray per light ray (its centre)."""
    params = SceneParams.from_scene(load_scene(scenes.path(name), RES))
    cap = capture_camera(params, surface=False)
    frame = es_frame.epipolar_frame_of(params)
    queries = es_queries.assign_queries(params, frame, es_frame.choose_slices(frame, 0), cap, RING_DEG)
    if params.light.kind == "directional":
        rays = es_directional.light_ray_grid(params, queries)
        lit = np.ones(queries.n * rays.d, bool)
        traced = es_blockers.trace_blocker_angles(params, queries, rays, 1)
    else:
        t_end_max = float(dr.max(queries.t_near)[0]) + float(dr.max(cap.d)[0])
        rays = ell_local.local_light_ray_grid(params, queries, 0, t_end_max)
        _, _, lit_mask = ell_local_light_factor.light_ray_factor(params, queries, rays, 1)
        lit = np.array(lit_mask, bool)          # existing light rays that carry light
        traced = ell_local_blockers.trace_local_blocker_angles(params, queries, rays, 1, lit=lit_mask)
    return params, cap, queries, rays, lit, traced


def texel_centre_angles(params, queries, rays, shadow_map) -> mi.Float:
    """β_b of each light ray's blocker if it were traced through the centre
    of the texel the resampled map reads for it (the nearest texel), with the
    map's own tracer (:func:`~integrators.core.capture.first_surface`, from the
    map's plane or the light) and its bias applied as the map applies it:
    what ``shadow_map_*blocker_angles`` must return if the only difference
    from ``traced`` is where the light ray is sampled."""
    frame = queries.frame
    s, gamma = es_blockers.sub_ray_gamma(rays, 1, 0)
    alpha = dr.gather(mi.Float, queries.alpha, s)
    res = shadow_map.res
    if frame.is_directional:
        base = light_coords_to_world(frame, alpha, gamma, 0.0)
        _, u, v, _ = shadow_map._coords(base)
        iu = mi.Float(dr.clip(dr.round(u), 0, res - 1))
        iv = mi.Float(dr.clip(dr.round(v), 0, res - 1))
        e1, e2, w = (mi.Vector3f(*map(float, x)) for x in shadow_map.frames[0])
        centre = base + e1 * ((iu - u) * shadow_map.du) + e2 * ((iv - v) * shadow_map.dv)
        origin = centre + w * (shadow_map.s0 - dr.dot(mi.Vector3f(centre), w))  # on the map plane
        si, _ = first_surface(params.scene, mi.Ray3f(origin, -w))
        u_b = dr.dot(mi.Vector3f(si.p - mi.Point3f(point(params.camera.origin))), w)
        return dr.select(si.is_valid(), dr.atan2(gamma, u_b - shadow_map.bias), math.pi)
    w = ell_local.light_ray_direction(frame, alpha, gamma)
    p_l = mi.Point3f(point(frame.light_position))
    face, u, v, _ = shadow_map._coords(p_l + w * float(frame.light_distance))
    iu = mi.Float(dr.clip(dr.round(u), 0, res - 1))
    iv = mi.Float(dr.clip(dr.round(v), 0, res - 1))
    right, up, fwd = (shadow_map._gather_frame(face, k) for k in range(3))
    a = ((iu + 0.5) / res * 2 - 1) * shadow_map.tan_half
    b = ((iv + 0.5) / res * 2 - 1) * shadow_map.tan_half
    si, _ = first_surface(params.scene, mi.Ray3f(p_l, dr.normalize(fwd + right * a + up * b)))
    r_b = dr.norm(mi.Vector3f(si.p - p_l))
    return dr.select(si.is_valid(), ell_local_blockers._eye_beta(frame, p_l + w * (r_b + shadow_map.bias)),
                     math.pi)


def _sweep_arrays(queries, rays):
    """NumPy (row, β, D) of the queries and the padded β table per row."""
    row = np.array(queries.row)
    beta = np.array(queries.beta)
    D = np.array(es_layout.rectified_depth(queries, rays))[row, np.array(queries.col)]
    return row, beta, D


def compare(traced, resampled, lit, queries, rays) -> dict:
    """The disagreement measures of the module doc (NumPy)."""
    bt, br = np.asarray(traced)[lit], np.asarray(resampled)[lit]
    blocked_t, blocked_r = bt < math.pi, br < math.pi
    both = blocked_t & blocked_r
    err = np.degrees(np.abs(bt[both] - br[both]))
    s = np.repeat(np.arange(queries.n), rays.d)[lit]
    idx_t = np.array(es_queries.searchsorted_rows(queries, mi.UInt32(s), mi.Float(bt)))
    idx_r = np.array(es_queries.searchsorted_rows(queries, mi.UInt32(s), mi.Float(br)))
    # visibility samples the sweep uses: query q, light ray g with g + 1/2 < D_q
    row, beta, D = _sweep_arrays(queries, rays)
    d = rays.d
    full_t = np.full(queries.n * d, math.pi)
    full_r = np.full(queries.n * d, math.pi)
    full_t[lit], full_r[lit] = bt, br
    St, Sr = full_t.reshape(queries.n, d)[row], full_r.reshape(queries.n, d)[row]
    used = (np.arange(d)[None, :] + 0.5 < D[:, None]) & lit.reshape(queries.n, d)[row]
    flips = ((beta[:, None] <= St) != (beta[:, None] <= Sr)) & used
    return {
        "rays": int(lit.sum()),
        "blocked": float(blocked_t.mean()),
        "status": float(np.mean(blocked_t != blocked_r)),
        "beta_p50": float(np.median(err)), "beta_p90": float(np.quantile(err, 0.9)),
        "beta_p99": float(np.quantile(err, 0.99)), "beta_mean": float(err.mean()),
        "index": float(np.mean(idx_t != idx_r)),
        "flips": float(flips.sum() / max(used.sum(), 1)),
    }


@functools.lru_cache(maxsize=None)
def measure(name: str, res: int) -> dict:
    """:func:`compare` of traced against resampled (``res``² map) and of the
    resampled map against the texel-centre trace (``explained_*``)."""
    params, cap, queries, rays, lit, traced = setup(name)
    shadow_map = capture_shadow_map(params, cap, res)
    resampled = light_model(params).resample_blockers(params, queries, rays, shadow_map, 1)
    centre = texel_centre_angles(params, queries, rays, shadow_map)
    out = compare(traced, resampled, lit, queries, rays)
    explained = compare(centre, resampled, lit, queries, rays)
    out.update({f"explained_{k}": v for k, v in explained.items()})
    return out


# --------------------------------------------------------------------------
# Tests
# --------------------------------------------------------------------------

#: flips (visibility samples the sweep uses that differ) allowed at a 256²
#: map, scaled by sqrt(256 / res): ~1.5x the measured values (module doc)
FLIPS_256 = {"grove": 0.12}
FLIPS_256_DEFAULT = 0.02
#: below these the bias floor is reached and a larger map need not win
FLOORS = {"beta_p50": 0.02, "beta_p90": 0.05, "beta_mean": 0.05, "index": 2e-3,
          "flips": 1e-3}


def check_explained(name: str, res: int) -> dict:
    """The resampled map is the one traced at texel centres (the disagreement
    is the resampling error and nothing else), and that error is small."""
    m = measure(name, res)
    assert m["rays"] > 1000
    assert m["explained_status"] < 1e-3, m
    assert m["explained_beta_p99"] < 5e-3, m             # degrees
    assert m["explained_index"] < 2e-3, m
    assert m["explained_flips"] < 1e-3, m
    assert m["status"] < 1e-3, m
    assert m["beta_p50"] < 0.2 * 256 / res + 0.02, m     # ~a texel, plus the bias floor
    assert m["flips"] < FLIPS_256.get(name, FLIPS_256_DEFAULT) * math.sqrt(256 / res), m
    return m


def check_shrinks(name: str, lo: int, hi: int) -> None:
    a, b = check_explained(name, lo), check_explained(name, hi)
    print(f"\n{name}: {lo}²: {a}\n{hi}²: {b}")
    assert b["status"] <= a["status"]
    for key, floor in FLOORS.items():
        assert b[key] <= 1.05 * a[key] or b[key] < floor, (key, a[key], b[key])
    assert b["beta_p90"] < 0.6 * a["beta_p90"], (a, b)   # a 4x finer map


@pytest.mark.parametrize("name", DIRECTIONAL + LOCAL)
def test_resampled_agrees_with_traced_and_converges(name):
    """Fast case: 256² and 1024² maps."""
    check_shrinks(name, *FAST_MAPS)


@pytest.mark.slow
@pytest.mark.parametrize("name", DIRECTIONAL + LOCAL)
def test_resampled_agrees_with_traced_at_paper_like_resolutions(name):
    """512² and 2048² maps (epipolar_tree's default ``shadowmap_resolution``
    is 2048; the paper used 4096² at 1280x960)."""
    check_shrinks(name, *SLOW_MAPS)

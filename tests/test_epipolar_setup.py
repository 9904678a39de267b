"""Rectified maps of integrators.epipolar.queries against per-sample NumPy oracles."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from integrators.epipolar import blockers as es_blockers
from integrators.epipolar import frame as es_frame
from integrators.epipolar import last_interval as es_last_interval
from integrators.epipolar import light_factor as es_light_factor
from integrators.epipolar.light_rays import directional as es_directional
from integrators.epipolar.light_rays import layout as es_layout
from integrators.epipolar import queries as es_queries
from integrators.epipolar import query_terms as es_query_terms
from integrators.core.capture import capture_camera
from integrators.epipolar.blockers import BlockerModes
from integrators.epipolar.light_models import light_model
from integrators.core.scene_params import SceneParams
from rectify import direction_to_alpha_beta_reference, pixel_to_slice_reference
from tests.conftest import scene_dict

RES = (32, 24)
SPHERE_C, SPHERE_R = np.array([0.0, 0.8, 0.0]), 0.4   # conftest's blocker
FLOOR_Y, FLOOR_HALF = -1.0, 3.0                        # conftest's floor


def setup(light=None, ring_deg=2.0, slices=0, **kw):
    scene = mi.load_dict(scene_dict(res=RES, **({"light": light} if light else {}), **kw))
    params = SceneParams.from_scene(scene)
    cap = capture_camera(params, surface=False)
    frame = es_frame.epipolar_frame_of(params)
    sl = es_frame.choose_slices(frame, slices)
    return params, cap, frame, sl, es_queries.assign_queries(params, frame, sl, cap, ring_deg)


def on_screen_light():
    """A light in front of the camera (epipole inside the image)."""
    return {"type": "directional", "direction": [0.05, -0.1, 1.0], "irradiance": 2.0}


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_queries_against_per_sample_numpy(light):
    """Every non-ring sample with d > 0 is a query of its nearest slice, at
    its own β and γ_end = t_end sin β, sorted by β within its row."""
    params, cap, frame, sl, q = setup(on_screen_light() if light else None, ring_deg=3.0)
    W, H = RES
    yy, xx = np.mgrid[0:H, 0:W]
    x, y = xx.ravel() + 0.5, yy.ravel() + 0.5
    _, beta = direction_to_alpha_beta_reference(frame, frame.camera.direction(x, y))
    _, _, k0, k1, f = pixel_to_slice_reference(frame, sl, x, y)
    nearest = np.where(f < 0.5, k0, k1)
    d = np.array(cap.d)
    ring = np.minimum(beta, np.pi - beta) < math.radians(3.0)
    expected = np.flatnonzero((d > 0) & ~ring)
    assert (light is None) == (not ring.any())

    sample, row, col = np.array(q.sample), np.array(q.row), np.array(q.col)
    assert sorted(sample.tolist()) == expected.tolist()
    assert sorted(np.array(q.ring_sample).tolist()) == np.flatnonzero(ring & (d > 0)).tolist()
    slice_of_query = np.array(q.slice_index)[row]
    clear = np.abs(f[sample] - 0.5) > 1e-3            # not a tie between two slices
    assert np.all(slice_of_query[clear] == nearest[sample][clear])
    qbeta = np.array(q.beta)
    np.testing.assert_allclose(qbeta, beta[sample], atol=2e-6)
    t_near = params.camera.near_clip / (frame.camera.direction(x, y)[sample]
                                        / np.linalg.norm(frame.camera.direction(x, y)[sample],
                                                         axis=1, keepdims=True)
                                        @ params.camera.forward)
    np.testing.assert_allclose(np.array(q.t_near), t_near, rtol=1e-4)
    np.testing.assert_allclose(np.array(q.gamma_end), (t_near + d[sample]) * np.sin(beta[sample]),
                               rtol=1e-5, atol=1e-6)
    # sweep order: rows contiguous, col = rank by β inside the row
    counts = np.array(q.r_count)
    assert q.r == counts.max() and counts.sum() == len(sample)
    assert np.all(np.diff(row) >= 0)
    for s in range(q.n):
        sel = row == s
        assert np.array_equal(col[sel], np.arange(counts[s]))
        assert np.all(np.diff(qbeta[sel]) >= 0)

    # depth D = γ_end / Δγ, Δγ = (max γ_end of the row) / d
    rays = es_directional.light_ray_grid(params, q, 40)
    D = np.array(es_layout.rectified_depth(q, rays))
    gmax = np.zeros(q.n)
    np.maximum.at(gmax, row, np.array(q.gamma_end))
    np.testing.assert_allclose(D[row, col], np.array(q.gamma_end) / (gmax[row] / 40), rtol=1e-5)
    assert np.all(D.max(axis=1) <= 40 + 1e-3)


@pytest.mark.parametrize("light", ["directional", "point"])
def test_light_ray_layouts_are_frozen_and_share_one_protocol(light):
    """Every layout is a frozen dataclass of the LightRayLayout protocol:
    ``d``, ``gamma_max``, ``delta_gamma``, ``lanes``, ``positions``,
    ``row_counts`` (None: all d); ``with_box_exits`` returns a copy.  The
    kernel evaluated at explicitly given points (``separate_kernel``'s
    ``points``, the projective map's path) equals the model's own layout."""
    import dataclasses

    from integrators.epipolar.kernel.separation import separate_kernel

    params, cap, frame, sl, q = setup(light)
    model = light_model(params)
    rays = model.light_rays(params, q, 16, cap)
    assert isinstance(rays, es_layout.LightRayLayout) and isinstance(rays, es_layout.EqualLightRays)
    with pytest.raises(dataclasses.FrozenInstanceError):
        rays.d = 3
    s, g, _ = rays.lanes()
    assert dr.width(s) == q.n * rays.d
    counts = rays.row_counts()
    assert (counts is None) == (light == "directional")
    if light == "directional":
        bare = es_directional.LightRays(rays.d, rays.gamma_max, rays.delta_gamma)
        exits = es_directional.with_box_exits(params, q, bare)
        assert bare.h is None and np.array_equal(np.array(exits.h), np.array(rays.h))
        own = separate_kernel(model.separation, params, q, rays, 0, 1e-3)
        given = separate_kernel(model.separation, params, q, rays, 0, 1e-3,
                                points=model.separation.kernel_points(q, rays))
        assert np.array_equal(np.array(own[0]), np.array(given[0]))
        assert np.array_equal(np.array(own[1]), np.array(given[1]))
    else:
        assert np.all(np.array(counts) <= rays.d)


def first_blocker_u(base, w):
    """NumPy oracle: largest u where the line base + u w meets the sphere or
    the floor rectangle (the first blocker coming from the light), or None."""
    hits = []
    oc = base - SPHERE_C
    b, c = oc @ w, oc @ oc - SPHERE_R ** 2
    disc = b * b - c
    if disc >= 0:
        hits.append(-b + math.sqrt(disc))
    if abs(w[1]) > 1e-12:
        u = (FLOOR_Y - base[1]) / w[1]
        p = base + u * w
        if abs(p[0]) <= FLOOR_HALF and abs(p[2]) <= FLOOR_HALF:
            hits.append(u)
    return max(hits) if hits else None


def assert_blocker_map(beta_b, expected):
    """Traced blocker angles against the ray oracle's (π: unblocked): both
    kinds present, > 99 % agree on blocked or not (the sphere is
    tessellation-free in Mitsuba: silhouettes and edges may flip), and the
    angles of those blocked in both agree to 2e-4 rad."""
    blocked = expected < np.pi
    assert blocked.any() and (~blocked).any()
    agree = (beta_b < np.pi) == blocked
    assert agree.mean() > 0.99, agree.mean()
    both = agree & blocked
    np.testing.assert_allclose(beta_b[both], expected[both], atol=2e-4)


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_traced_blocker_map_against_ray_oracle(light):
    params, cap, frame, sl, q = setup(on_screen_light() if light else None)
    rays = es_directional.light_ray_grid(params, q, 24)
    beta_b = np.array(es_blockers.trace_blocker_angles(params, q, rays, k=1)).reshape(q.n, 24)
    alpha = np.array(q.alpha, np.float64)
    dg = np.array(rays.delta_gamma, np.float64)
    o, w = params.camera.origin, frame.axis
    expected = np.full((q.n, 24), np.pi)
    for s in range(q.n):
        perp = math.cos(alpha[s]) * frame.b1 + math.sin(alpha[s]) * frame.b2
        for g in range(24):
            gamma = (g + 0.5) * dg[s]
            u_b = first_blocker_u(o + gamma * perp, w)
            if u_b is not None:
                expected[s, g] = math.atan2(gamma, u_b)
    assert_blocker_map(beta_b, expected)


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_adaptive_blocker_angles_match_traced_sub_rays(light):
    """adaptive: sub-rays interpolated between traced interval boundaries
    where the blockers are smooth land in the same depth mode (row
    searchsorted index) as tracing every sub-ray; the floor is a plane, so
    its interpolated angles are exact."""
    params, cap, frame, sl, q = setup(on_screen_light() if light else None)
    k, d = 4, 48
    rays = es_directional.light_ray_grid(params, q, d)
    s, gamma = es_blockers.adaptive_sub_ray_gamma(rays, k)      # every sub-ray traced there
    full = es_blockers._blocker_angle(params, q, s, gamma)
    fast = es_blockers.trace_blocker_angles(params, q, rays, k=k, adaptive=True)
    same = np.array(es_queries.searchsorted_rows(q, s, full)) == np.array(es_queries.searchsorted_rows(q, s, fast))
    assert same.mean() > 0.995, same.mean()
    a, b = np.array(full), np.array(fast)
    assert np.all(np.isfinite(b)) and np.all((b >= 0) & (b <= np.pi))
    both = (a < np.pi) & (b < np.pi)
    assert np.quantile(np.abs(a - b)[both], 0.95) < 1e-4
    # the index bounds of the interpolated sub-rays only shorten the search
    bounded = es_blockers.trace_sub_ray_blockers(params, q, rays, k=k, adaptive=True)
    assert bounded.lo is not None
    with_bounds, without = (es_blockers.blocker_modes(q, rays, x, k) for x in (bounded, bounded.angle))
    np.testing.assert_array_equal(np.array(with_bounds.beta), np.array(without.beta))
    np.testing.assert_array_equal(np.array(with_bounds.weight), np.array(without.weight))


def test_blocker_modes_are_row_searchsorted():
    """Blocker β -> view-ray index = number of the row's queries with β_q ≤ β_b."""
    params, cap, frame, sl, q = setup(on_screen_light())
    k = 3
    rays = es_directional.light_ray_grid(params, q, 16)
    beta_b = es_blockers.trace_blocker_angles(params, q, rays, k=k)
    modes = es_blockers.blocker_modes(q, rays, beta_b, k)
    bb = np.array(beta_b).reshape(q.n, 16, k)
    row, qbeta = np.array(q.row), np.array(q.beta)
    idx = np.empty_like(bb)
    for s in range(q.n):
        idx[s] = np.searchsorted(qbeta[row == s], bb[s], side="right")
    b, w = np.array(modes.beta), np.array(modes.weight)
    # merged modes: for every index value, the weights add up to count/k
    for s in range(q.n):
        for g in range(16):
            vals, counts = np.unique(idx[s, g], return_counts=True)
            got = {v: w[s, g][b[s, g] == v].sum() for v in vals}
            for v, c in zip(vals, counts):
                assert got[v] == pytest.approx(c / k)
            assert w[s, g].sum() == pytest.approx(1.0)


def test_merge_modes():
    index = mi.UInt32([5, 5, 7, 5, 9, 9, 9, 9])          # two light rays, k = 4
    b, w = es_blockers.merge_modes(index, 4)
    np.testing.assert_allclose(np.array(w), [0.75, 0, 0.25, 0, 1, 0, 0, 0])
    np.testing.assert_allclose(np.array(b)[[0, 2, 4]], [5, 7, 9])


def test_light_side_factor_against_slab_oracle():
    params, cap, frame, sl, q = setup(sigma_t={"type": "rgb", "value": [0.1, 0.3, 0.9]})
    rays = es_directional.light_ray_grid(params, q, 8)
    L = np.array(es_light_factor.light_side_factor(params, q, rays))
    assert L.shape == (q.n, 8, 3)
    alpha, dg = np.array(q.alpha, np.float64), np.array(rays.delta_gamma, np.float64)
    h_ref = np.array(rays.h_ref, np.float64)
    med = params.medium
    for s in range(0, q.n, 7):
        perp = math.cos(alpha[s]) * frame.b1 + math.sin(alpha[s]) * frame.b2
        for g in range(8):
            base = params.camera.origin + (g + 0.5) * dg[s] * perp
            with np.errstate(divide="ignore"):
                t0, t1 = (med.bounds_min - base) / frame.axis, (med.bounds_max - base) / frame.axis
            h = np.min(np.maximum(t0, t1))
            np.testing.assert_allclose(L[s, g], np.exp(-med.sigma_t * (h - h_ref[s])), rtol=1e-4)
    assert np.all(L <= 1.0)


def test_grey_sigma_t_gives_one_channel():
    params, cap, frame, sl, q = setup()
    rays = es_directional.light_ray_grid(params, q, 8)
    assert tuple(es_light_factor.light_side_factor(params, q, rays).shape) == (q.n, 8)


def test_first_leaf_visibility():
    modes = BlockerModes(mi.TensorXf(np.array([[[0, 3], [0, 0]], [[2, 9], [0, 0]]], np.float32)),
                         mi.TensorXf(np.array([[[0.5, 0.5], [1, 0]], [[1, 0], [1, 0]]],
                                              np.float32)))
    q = es_queries.EpipolarQueries(None, None, 2, 4, None, None, None, None,
                           mi.UInt32([0, 0, 1, 1]), mi.UInt32([0, 3, 1, 2]),
                           None, None, None, None, 4)
    np.testing.assert_allclose(np.array(es_query_terms.first_leaf_visibility(q, modes)), [0.5, 0, 1, 0])


def test_ring_and_zero_depth_samples_are_no_queries():
    params, cap, frame, sl, q = setup(on_screen_light(), ring_deg=10.0)
    assert dr.width(q.ring_sample) > 0
    betas = np.array(q.beta)
    assert np.all(np.minimum(betas, np.pi - betas) >= math.radians(10.0) - 1e-6)


# --------------------------------------------------------------------------
# Point and spot lights (Baran §9; integrators.epipolar.kernel.local)
# --------------------------------------------------------------------------

from types import SimpleNamespace  # noqa: E402

from hypothesis import given, settings  # noqa: E402
from hypothesis import strategies as st  # noqa: E402

from integrators.epipolar.kernel import local as ll_kernel_local
from integrators.epipolar.light_rays import local as ll_light_rays_local
from integrators.epipolar import local_blockers as ll_local_blockers
from integrators.epipolar import local_light_factor as ll_local_light_factor
from rectify import make_camera, point_frame, world_to_light_coords_reference  # noqa: E402

POINT_LIGHT = np.array([0.3, 2.0, 0.4])          # conftest LIGHTS["point"]


def light_ray_dirs(frame, alpha, gamma):
    """NumPy: unit direction from the light of light ray (α, γ)."""
    perp = np.cos(alpha)[..., None] * frame.b1 + np.sin(alpha)[..., None] * frame.b2
    return np.sin(gamma)[..., None] * perp - np.cos(gamma)[..., None] * frame.axis


def test_point_light_frame_and_queries():
    """§9: the frame's axis points at the light; γ_end is the angle at the
    light between the light ray through the query's end point and the
    direction light -> eye, inside (0, π − β)."""
    params, cap, frame, sl, q = setup("point")
    assert frame.light_kind == "point" and not frame.is_directional
    np.testing.assert_allclose(frame.light_position, POINT_LIGHT)
    np.testing.assert_allclose(frame.axis * frame.light_distance,
                               POINT_LIGHT - params.camera.origin, atol=1e-12)
    sample = np.array(q.sample)
    t_end = np.array(q.t_near) + np.array(cap.d)[sample]
    end = params.camera.origin + np.array(cap.omega).T[sample] * t_end[:, None]
    _, gamma, _ = world_to_light_coords_reference(frame, end)
    np.testing.assert_allclose(np.array(q.gamma_end), gamma, atol=2e-5)
    beta = np.array(q.beta)
    assert np.all(np.array(q.gamma_end) < np.pi - beta)


def test_local_light_rays_form_one_lattice():
    """One Δγ for every row; row s starts at m_s·Δγ, ≤ d light rays, and its
    light rays cover its lit range: [0, max γ_end] (point) or that range
    clipped to the cone (spot); dark rows get one light ray."""
    d = 32
    for light in ("point", "spot"):
        params, cap, frame, sl, q = setup(light)
        rays = ll_light_rays_local.local_light_ray_grid(params, q, d)
        delta = np.array(rays.delta_gamma)
        assert np.all(delta == delta[0])
        m, count, lo = np.array(rays.offset), np.array(rays.d_count), np.array(rays.gamma_lo)
        np.testing.assert_allclose(lo, m * delta[0], rtol=1e-6, atol=1e-7)
        assert np.all((count >= 1) & (count <= d))
        assert rays.lattice_size == m.max() + d
        a, b, lit = (np.array(v) for v in ll_light_rays_local.light_ray_range(params, q))
        end = lo + count * delta[0]
        assert np.all(lo[lit] <= a[lit] + 1e-6) and np.all(end[lit] >= b[lit] - 1e-6)
        gmax = np.zeros(q.n)
        np.maximum.at(gmax, np.array(q.row), np.array(q.gamma_end))
        if light == "point":
            assert lit.all() and np.all(m == 0)
            np.testing.assert_allclose(b, gmax, rtol=1e-6)
        else:
            assert lit.any() and np.all(count[~lit] == 1)
        D = np.array(es_layout.rectified_depth(q, rays))
        row, col = np.array(q.row), np.array(q.col)
        np.testing.assert_allclose(D[row, col], (np.array(q.gamma_end) - lo[row]) / delta[0],
                                   rtol=1e-4, atol=1e-3)


def test_automatic_light_ray_spacing_follows_the_image_with_a_floor_in_the_cone():
    """Automatic d: Δγ = the image's widest row [0, max γ_end] / (d − 1) --
    a wide spot cone takes its share of the image's d light rays, not d of
    its own (spot_room 640x480: 3.13M -> 1.21M light rays) -- but at least
    MIN_AUTO_LIGHT_RAYS across a narrow cone's widest lit row (seed 84);
    an explicit d spans the widest lit row; a point light's rows are all lit."""
    F = lambda *v: mi.Float(list(map(float, v)))
    B = lambda *v: mi.Bool(list(v))
    d = 800
    narrow = ll_light_rays_local.light_ray_spacing(F(0.10, 0.0), F(0.11, 0.9), B(True, False), d, True, F(1.0, 0.9))
    assert narrow == pytest.approx(0.01 / (es_directional.MIN_AUTO_LIGHT_RAYS - 1), rel=1e-5)
    wide = ll_light_rays_local.light_ray_spacing(F(0.1, 0.0), F(0.9, 0.9), B(True, False), d, True, F(1.0, 0.9))
    assert wide == pytest.approx(1.0 / (d - 1), rel=1e-5)
    explicit = ll_light_rays_local.light_ray_spacing(F(0.1, 0.0), F(0.9, 0.9), B(True, False), d, False, F(1.0, 0.9))
    assert explicit == pytest.approx(0.8 / (d - 1), rel=1e-5)
    point = ll_light_rays_local.light_ray_spacing(F(0.0, 0.0), F(1.0, 0.5), B(True, True), d, True, F(1.0, 0.5))
    assert point == pytest.approx(1.0 / (d - 1), rel=1e-5)


@settings(max_examples=25, deadline=None)
@given(axis=st.tuples(*[st.floats(-1, 1)] * 3).filter(lambda v: np.linalg.norm(v) > 0.1),
       cutoff=st.floats(5.0, 90.0), alpha=st.floats(-math.pi, math.pi))
def test_cone_interval_against_brute_force(axis, cutoff, alpha):
    """cone_interval = the γ ∈ [0, π] of slice α whose light ray is inside
    the spot cone (angle to the spot axis < cutoff), up to CONE_MARGIN."""
    cam = make_camera([0.0, 0.0, 0.0], [0.0, 0.0, -1.0])
    frame = point_frame(cam, [0.3, 1.0, -2.0], kind="spot")
    a = np.asarray(axis) / np.linalg.norm(axis)
    params = SimpleNamespace(light=SimpleNamespace(kind="spot", spot_axis=a, cutoff_angle=cutoff))
    lo, hi, lit = (np.array(v)[0] for v in ll_light_rays_local.cone_interval(params, frame, mi.Float(alpha)))
    gamma = np.linspace(0.0, math.pi, 20001)
    w = light_ray_dirs(frame, np.full_like(gamma, alpha), gamma)
    inside = w @ a > math.cos(math.radians(cutoff))
    if not inside.any():
        assert not lit or hi - lo < 3 * ll_light_rays_local.CONE_MARGIN
        return
    assert lit
    eps = 2 * ll_light_rays_local.CONE_MARGIN + 2e-4
    assert lo - eps <= gamma[inside].min() and gamma[inside].max() <= hi + eps
    assert gamma[inside].min() <= lo + eps and hi - eps <= gamma[inside].max()


def first_hit_distance(origin, w):
    """NumPy oracle: distance along unit w from origin to the sphere or the
    floor rectangle (conftest's blockers), or None."""
    hits = []
    oc = origin - SPHERE_C
    b, c = oc @ w, oc @ oc - SPHERE_R ** 2
    disc = b * b - c
    if disc >= 0:
        hits += [s for s in (-b - math.sqrt(disc), -b + math.sqrt(disc)) if s > 0]
    if abs(w[1]) > 1e-12:
        s = (FLOOR_Y - origin[1]) / w[1]
        p = origin + s * w
        if s > 0 and abs(p[0]) <= FLOOR_HALF and abs(p[2]) <= FLOOR_HALF:
            hits.append(s)
    return min(hits) if hits else None


def test_traced_local_blockers_against_ray_oracle():
    """β_b = the eye's angle of the first blocker seen from the point light
    along each light ray (centre, k = 1); π if nothing blocks it."""
    params, cap, frame, sl, q = setup("point")
    rays = ll_light_rays_local.local_light_ray_grid(params, q, 24)
    beta_b = np.array(ll_local_blockers.trace_local_blocker_angles(params, q, rays, k=1)).reshape(q.n, 24)
    alpha = np.array(q.alpha, np.float64)
    lo, delta = np.array(rays.gamma_lo, np.float64), float(rays.delta_gamma[0])
    expected = np.full((q.n, 24), np.pi)
    for s in range(q.n):
        w = light_ray_dirs(frame, np.full(24, alpha[s]), lo[s] + (np.arange(24) + 0.5) * delta)
        for g in range(24):
            r_b = first_hit_distance(POINT_LIGHT, w[g])
            if r_b is not None:
                v = POINT_LIGHT + r_b * w[g] - params.camera.origin
                expected[s, g] = math.atan2(np.linalg.norm(np.cross(v, frame.axis)), v @ frame.axis)
    assert_blocker_map(beta_b, expected)


def test_blocked_light_ray_shades_exactly_the_later_view_rays():
    """On a light ray γ, r = L sin β / sin(β+γ) grows with β (§9 visibility
    rule): points beyond the blocker (r > r_b) are exactly those with β > β_b."""
    L = 2.7
    for gamma in (0.05, 0.7, 1.9, 3.0):
        beta = np.linspace(1e-3, math.pi - gamma - 1e-3, 2001)
        r = L * np.sin(beta) / np.sin(beta + gamma)
        assert np.all(np.diff(r) > 0)
        r_b = 0.5 * (r[1000] + r[1001])
        beta_b = math.atan2(r_b * math.sin(gamma), L - r_b * math.cos(gamma))  # the blocker's β
        np.testing.assert_array_equal(r > r_b, beta > beta_b)


@pytest.mark.parametrize("light", ["point", "spot", "spot_textured"])
def test_light_ray_factor_against_mitsuba_intensity(light):
    """L(α, γ) = Mitsuba's intensity toward the light ray (sampled by
    sample_direction at world points built in NumPy) times e^{-σt L} (the
    light is inside the box: r_in = 0), with the colour factored out when the
    light is untextured; k = 1: the light ray's centre."""
    params, cap, frame, sl, q = setup(light)
    rays = ll_light_rays_local.local_light_ray_grid(params, q, 16)
    L, colour, lit = ll_local_light_factor.light_ray_factor(params, q, rays, k=1)
    L = np.array(L)
    assert (L.ndim == 3) == (light == "spot_textured")
    alpha = np.array(q.alpha, np.float64)
    lo, delta = np.array(rays.gamma_lo, np.float64), float(rays.delta_gamma[0])
    count = np.array(rays.d_count)
    s, g = np.divmod(np.arange(q.n * 16), 16)
    w = light_ray_dirs(frame, alpha[s], lo[s] + (g + 0.5) * delta)
    x = POINT_LIGHT if light == "point" else params.light.position
    pts = x + w * 0.5
    it = dr.zeros(mi.Interaction3f)
    it.p = mi.Point3f(*(mi.Float(pts[:, i].astype(np.float32)) for i in range(3)))
    ds, spec = params.light.emitter.sample_direction(it, mi.Point2f(0.5, 0.5))
    I = np.array(mi.Color3f(spec)).T.reshape(-1, 3) * 0.25          # · r², r = 0.5
    expected = I * np.exp(-params.medium.sigma_t[0] * frame.light_distance)
    got = L.reshape(q.n * 16, -1) * np.array(colour).reshape(1, -1)
    used = g < count[s]
    np.testing.assert_allclose(got[used], expected[used], rtol=2e-3, atol=1e-6 * expected.max())
    assert np.all(got[~used] == 0)
    assert np.array_equal(np.array(lit).astype(bool), used & (I.max(1) > 0))


@settings(max_examples=40, deadline=None)
@given(beta=st.floats(0.02, math.pi - 0.05), frac=st.floats(0.01, 0.98),
       sigma_t=st.floats(0.0, 3.0), g=st.floats(-0.8, 0.8))
def test_local_kernel_against_triangle_geometry(beta, frac, sigma_t, g):
    """K(γ, β) = e^{-σt (t + r − L)} f_p with t, r from the law of sines and
    Mitsuba's HG at cos θ = −cos(β+γ) (DESIGN §1 convention), Dr.Jit and
    NumPy versions, inside the queries' range (x ≤ x_max)."""
    L = 1.7
    gamma = frac * (math.pi - beta)
    t = L * math.sin(gamma) / math.sin(beta + gamma)
    r = L * math.sin(beta) / math.sin(beta + gamma)
    cos_theta = -math.cos(beta + gamma)
    hg = (1 - g * g) / (4 * math.pi * (1 + g * g + 2 * g * cos_theta) ** 1.5)
    expected = math.exp(-sigma_t * (t + r - L)) * hg
    x = math.tan(beta / 2) * math.tan(gamma / 2)
    scene = mi.load_dict(scene_dict(light="point", res=(4, 3), phase={"type": "hg", "g": g}))
    params = SceneParams.from_scene(scene)
    got = float(ll_kernel_local.local_kernel(params, sigma_t, L, min(x + 1e-3, 1 - 1e-6),
                                math.tan(beta / 2), gamma)[0])
    assert got == pytest.approx(expected, rel=2e-3, abs=1e-30)
    K = ll_kernel_local.local_kernel_numpy(params, sigma_t, L, min(x + 1e-3, 1 - 1e-6))
    assert float(K(gamma, beta)) == pytest.approx(expected, rel=1e-4, abs=1e-300)


def test_attenuation_exponent_is_continued_c1():
    """E(x) = k x/(1 − x) up to x_max, then its tangent line (C¹)."""
    k, xm = 3.0, 0.8
    x = np.array([xm - 1e-7, xm, xm + 1e-7, 0.95, 2.0])
    E, dE = ll_kernel_local.attenuation_exponent(x, xm, k)
    assert E[0] == pytest.approx(k * x[0] / (1 - x[0]))
    assert E[2] - E[1] == pytest.approx(1e-7 * k / (1 - xm) ** 2, rel=1e-4)
    np.testing.assert_allclose(dE[2:], k / (1 - xm) ** 2)
    Ed, dEd = ll_kernel_local.attenuation_exponent(mi.Float(x.astype(np.float32)), xm, k)
    np.testing.assert_allclose(np.array(Ed), E, rtol=1e-5)
    np.testing.assert_allclose(np.array(dEd), dE, rtol=1e-5)


@pytest.mark.parametrize("phase", [None, {"type": "hg", "g": 0.6}])
@pytest.mark.parametrize("beta,gamma,delta,sigma_t", [
    (1.0, 0.3, 0.05, 0.3),        # smooth
    (3.08, 0.0, 0.02, 2.0),       # toward the anti-epipole: E bends from 0 to 3.9
    (3.1, 0.0, 0.03, 5.0),        # ... and decays by e^{-400} in the interval
    (0.2, 1.5, 0.2, 1.0),         # a wide interval
])
def test_cell_mean_against_quadrature(phase, beta, gamma, delta, sigma_t):
    """LocalKernel.cell_mean = the mean of K over [γ, γ+Δγ] (fine midpoint
    quadrature of local_kernel), also where K decays by e^{-300} in it."""
    scene = mi.load_dict(scene_dict(light="point", res=(4, 3), phase=phase))
    params = SceneParams.from_scene(scene)
    L, x_max = 2.0, 1 - 1e-6
    n = 20000
    g = gamma + (np.arange(n) + 0.5) / n * delta
    ok = np.tan(beta / 2) * np.tan(g / 2) < 1
    values = np.where(ok, np.array(ll_kernel_local.local_kernel(params, sigma_t, L, x_max, math.tan(beta / 2),
                                                   mi.Float(g.astype(np.float32)))), 0.0)
    expected = values.mean()
    got = float(ll_kernel_local.local_kernel(params, sigma_t, L, x_max, math.tan(beta / 2), gamma, delta)[0])
    assert got == pytest.approx(expected, rel=5e-3)


@pytest.mark.parametrize("light,phase,sigma_t", [("point", None, 0.3),
                                                ("spot", {"type": "hg", "g": 0.5}, 1.5)])
def test_separated_local_kernel_reproduces_the_cell_means(light, phase, sigma_t):
    """Σ_i A_i B_i at (row, light ray, query) = the cell mean of K at the
    query's β, for every light ray its depth covers (relative L2 per query
    within a few times the SVD tolerance)."""
    params, cap, frame, sl, q = setup(light, phase=phase, sigma_t=sigma_t)
    rays = ll_light_rays_local.local_light_ray_grid(params, q, 24)
    tol = 1e-4
    A, B = light_model(params).separated_kernel(params, q, rays, 0, tol)
    A, B = np.array(A)[:, :, 0], np.array(B)[:, :, 0]            # (n, d, N), (n, r, N)
    x_max = ll_kernel_local.query_x_max(q)
    L = float(frame.light_distance)
    delta = float(rays.delta_gamma[0])
    lo, count = np.array(rays.gamma_lo), np.array(rays.d_count)
    row, col, beta = np.array(q.row), np.array(q.col), np.array(q.beta)
    D = np.array(es_layout.rectified_depth(q, rays))[row, col]
    pick = np.arange(0, q.count, 17)
    errs = []
    for j in pick:
        s, c = row[j], col[j]
        cells = np.arange(min(int(np.ceil(D[j])), count[s]))
        if cells.size == 0:
            continue
        approx = A[s, cells] @ B[s, c]
        exact = np.array(ll_kernel_local.local_kernel(params, sigma_t, L, x_max, math.tan(beta[j] / 2),
                                         mi.Float((lo[s] + cells * delta).astype(np.float32)),
                                         delta))
        errs.append(np.linalg.norm(approx - exact) / np.linalg.norm(exact))
    assert len(errs) > 20, len(errs)
    assert np.median(errs) < 10 * tol and max(errs) < 1e-2, (np.median(errs), max(errs))


@pytest.mark.parametrize("coloured", [False, True])
def test_last_interval_correction_against_numpy(coloured):
    """Sweep + :func:`es_last_interval.last_interval_correction` = the direct sum of Eq. 3
    with the visibility of each view ray's last leaf k0 = ⌊D⌋ replaced by
    the query's own V (here random 0/1), the coverage weights unchanged."""
    from integrators.tree.partial_sum_tree import integrate_slices
    from integrators.tree.partial_sum_reference import random_problem
    n, d, r, N = 3, 8, 6, 2
    D, S, A, B, L = random_problem(n, d, r, N, seed=3, modes=2)
    if coloured:
        A = np.stack([A, 0.5 * A, 2 * A], axis=2)              # (1, d, 3, N)
    rng = np.random.default_rng(1)
    q = es_queries.EpipolarQueries(None, None, n, r, None, None, None, mi.UInt32(np.arange(n * r)),
                           mi.UInt32(np.repeat(np.arange(n), r)),
                           mi.UInt32(np.tile(np.arange(r), n)), None, None, None, None, n * r)
    modes = BlockerModes(mi.TensorXf(S.beta), mi.TensorXf(S.weight))
    Dc = np.clip(D, 0, d)
    k0 = np.minimum(np.floor(Dc), d - 1).astype(np.int64)
    f = (Dc - k0).astype(np.float32)
    V_leaf = es_blockers.leaf_visibility(q, modes, mi.UInt32(k0.ravel()))
    V_new = rng.integers(0, 2, n * r).astype(np.float32)
    last = es_last_interval.LastInterval(mi.UInt32(k0.ravel()), mi.Float(f.ravel()), V_leaf,
                           mi.Float(V_new), mi.UInt32(np.arange(n * r)))
    At, Bt, Lt = mi.TensorXf(A), mi.TensorXf(B), mi.TensorXf(L)
    got = es_queries.gather_queries(q, integrate_slices(mi.TensorXf(D), modes, At, Bt, L=Lt))
    got = np.array(got + es_last_interval.last_interval_correction(q, At, Bt, Lt, last)).T    # (Q, 3)

    # NumPy: V[s, β, γ] from the modes (applied from ⌈β_m⌉ on), last leaf replaced
    onset = np.ceil(S.beta)                                         # (n, d, M)
    acts = onset[:, None, :, :] <= np.arange(r)[None, :, None, None]
    V = 1.0 - (acts * S.weight[:, None]).sum(-1)                     # (n, r, d)
    s_idx, b_idx = np.divmod(np.arange(n * r), r)
    np.testing.assert_allclose(np.array(V_leaf), V[s_idx, b_idx, k0.ravel()], atol=1e-6)
    V[s_idx, b_idx, k0.ravel()] = V_new
    cover = np.clip(Dc[..., None] - np.arange(d), 0.0, 1.0)         # (n, r, d)
    A4 = A if coloured else A[:, :, None, :]                         # (1, d, C, N)
    leaf = A4[0][None] * L[:, :, None, None]                         # (n, d, C, N)
    want = np.einsum("sbg,sgcn,bn->sbc", V * cover, leaf, B[0]).reshape(n * r, -1)
    np.testing.assert_allclose(got, np.broadcast_to(want, got.shape), rtol=1e-4, atol=1e-5)


def test_light_side_factor_times_reference_is_bounded():
    """e^{-σt h_ref} · L(γ) ≤ e^{c} for every light ray, and a light ray is
    dropped exactly when σt·h < −c (row_reference, light_side_factor)."""
    from experiments import stability as st

    sigma_t = 10.0
    scene = mi.load_dict(st.stress_scene(st.grazing_cases([sigma_t])[0]["light"],
                                         sigma_t=sigma_t, res=(32, 24), camera=st.UNDER_TOP))
    params = SceneParams.from_scene(scene)
    frame = es_frame.epipolar_frame_of(params)
    queries = es_queries.assign_queries(params, frame, es_frame.choose_slices(frame),
                                capture_camera(params, surface=False), 2.0)
    rays = es_directional.light_ray_grid(params, queries)
    L = np.array(es_light_factor.light_side_factor(params, queries, rays)).reshape(queries.n, rays.d)
    h = np.array(rays.h).reshape(queries.n, rays.d)
    h_ref = np.array(rays.h_ref)
    c = es_directional.LIGHT_SIDE_RANGE
    assert np.min(h[np.isfinite(h)]) * sigma_t < -c          # the case needs the bound
    assert np.all(h_ref >= -c / sigma_t - 1e-5)
    amplified = np.exp(-sigma_t * h_ref)[:, None] * L
    assert np.all(amplified <= np.exp(c) * (1 + 1e-4))
    dropped = np.isfinite(h) & (sigma_t * h < -c)
    assert np.all(L[dropped] == 0) and np.all(L[np.isfinite(h) & ~dropped] > 0)


@pytest.mark.parametrize("light", [None, "on_screen"])
def test_slice_interpolation_shares_each_sample_between_its_neighbours(light):
    """interpolate=True: every non-ring sample's queries have weights summing
    to 1; a sample with two weighted queries has them in the two slices
    around its α and reproduces α by their weighted mean (the lerp); a lone
    sample (a neighbour nobody's nearest) has weight 1 in its nearest slice
    and a weight-0 query in the used slice (some sample's nearest) on its
    other side, for the disagreement test; one within SNAP of a slice has a
    single query, in its nearest slice; each row is still sorted by β."""
    scene = mi.load_dict(scene_dict(res=RES, **({"light": on_screen_light()} if light else {})))
    params = SceneParams.from_scene(scene)
    cap = capture_camera(params, surface=False)
    frame = es_frame.epipolar_frame_of(params)
    sl = es_frame.choose_slices(frame)
    q = es_queries.assign_queries(params, frame, sl, cap, 3.0, interpolate=True)
    nearest = es_queries.assign_queries(params, frame, sl, cap, 3.0)
    alpha_s, _ = direction_to_alpha_beta_reference(frame, np.array(cap.omega).T)
    sample, w = np.array(q.sample), np.array(q.weight)
    a_q = np.array(q.alpha)[np.array(q.row)]
    assert set(sample) == set(np.array(nearest.sample))
    total = np.bincount(sample, w, len(alpha_s))
    np.testing.assert_allclose(total[np.array(nearest.sample)], 1.0, atol=1e-6)
    # slices' α relative to the sample's own (unwrapped around it)
    d = np.angle(np.exp(1j * (a_q - alpha_s[sample])))
    counts = np.bincount(sample, minlength=len(alpha_s))
    assert counts.max() == 2 and 0.5 < np.mean(counts[counts > 0] == 2)
    lone_q = (w == 0.0)
    lone = np.zeros(len(alpha_s), bool)
    lone[sample[lone_q]] = True
    assert lone.any()
    pairs = np.flatnonzero((counts == 2) & ~lone)
    mean_offset = np.bincount(sample, w * d, len(alpha_s))[pairs]
    spacing = np.max(np.abs(np.diff(np.asarray(sl.alpha))))
    assert np.max(np.abs(mean_offset)) < 1e-3 * spacing + 1e-6
    assert np.max(np.abs(d[~lone_q])) <= spacing * (1 + 1e-4)
    # every pair brackets its sample: a slice on each side
    lo = np.full(len(alpha_s), np.inf)
    hi = np.full(len(alpha_s), -np.inf)
    np.minimum.at(lo, sample, d)
    np.maximum.at(hi, sample, d)
    both = np.flatnonzero(counts == 2)
    assert np.all(lo[both] <= 1e-6) and np.all(hi[both] >= -1e-6)
    # the weight-1 query of a lone or single sample is in its nearest slice;
    # a lone sample's weight-0 query in a used slice
    near_alpha = dict(zip(np.array(nearest.sample), np.array(nearest.alpha)[np.array(nearest.row)]))
    whole = w == 1.0
    np.testing.assert_array_equal(a_q[whole], [near_alpha[i] for i in sample[whole]])
    assert np.all(np.isin(a_q[lone_q], np.array(nearest.alpha)))
    rows, beta = np.array(q.row), np.array(q.beta)
    order = np.lexsort((np.array(q.col), rows))
    assert np.all(np.diff(rows[order]) >= 0)
    same = np.diff(rows[order]) == 0
    assert np.all(np.diff(beta[order])[same] >= -1e-5)


def _magnitude_problem(coloured, seed=5, n=3, d=300, r=40, N=3):
    """Random separated factors, a dominant first term and others of mixed
    signs (partial sums that cancel), an L growing along γ
    by e^{±6} per row, and queries ending anywhere."""
    rng = np.random.default_rng(seed)
    scale = np.array([1.0, 0.3, 0.1], np.float32)[:N]
    A = rng.normal(size=(n, d, 3, N) if coloured else (1, d, N)).astype(np.float32) * scale
    A[..., 0] = np.abs(A[..., 0])
    B = rng.normal(size=(1, r, N)).astype(np.float32)
    B[0, ::3, 0] *= 1e-3               # these queries' sums cancel: U ≪ M
    L = np.exp(np.linspace(0, 1, d)[None] * rng.uniform(-6, 6, (n, 1))).astype(np.float32)
    q = es_queries.EpipolarQueries(None, None, n, r, None, None, None, mi.UInt32(np.arange(n * r)),
                           mi.UInt32(np.repeat(np.arange(n), r)),
                           mi.UInt32(np.tile(np.arange(r), n)), None, None, None, None, n * r)
    k0 = rng.integers(0, d, n * r)
    f = rng.uniform(0, 1, n * r).astype(np.float32)
    last = es_last_interval.LastInterval(mi.UInt32(k0), mi.Float(f), None, None, mi.UInt32([]))
    # NumPy: Σ_{γ<k0} + f · leaf k0, per channel
    A4 = A if coloured else np.broadcast_to(A[:, :, None, :], (1, d, 3, N))
    v = A4 * L[:, :, None, None]                                       # (n, d, 3, N)
    s, b = np.divmod(np.arange(n * r), r)
    cover = np.clip(k0[:, None] + f[:, None] - np.arange(d)[None], 0.0, 1.0)   # (Q, d)
    vq = v[s if v.shape[0] > 1 else np.zeros_like(s)]
    U = np.einsum("qg,qgcn,qn->qc", cover, vq.astype(np.float64), B[0][b])
    M = np.einsum("qg,qgcn,qn->qc", cover, np.abs(vq.astype(np.float64)), np.abs(B[0][b]))
    return q, mi.TensorXf(A), mi.TensorXf(B), mi.TensorXf(L), last, U, M


@pytest.mark.parametrize("coloured", [False, True])
def test_sweep_magnitude_against_numpy(coloured):
    """:func:`es_last_interval.sweep_magnitude`'s M and U are the exact sums Σ_{γ<D} of the
    magnitudes and of Eq. 3's unshadowed separated terms, the last leaf
    counted with its covered fraction, per query and channel (rows whose L
    grows or decays by e^6 along γ; queries whose sums cancel)."""
    q, A, B, L, last, U_np, M_np = _magnitude_problem(coloured)
    M, U = es_last_interval.sweep_magnitude(q, A, B, L, last)
    np.testing.assert_allclose(np.array(M).T, M_np, rtol=2e-5)
    np.testing.assert_allclose(np.array(U).T, U_np, rtol=2e-5, atol=2e-5 * M_np.max())
    got_bad = np.array(M).T * es_last_interval.UNRESOLVED_RATIO > np.abs(np.array(U).T)
    assert got_bad.any() and not got_bad.all()


def test_the_phase_table_is_read_once_per_phase_function():
    """The SVD's phase table (and an isotropic phase's constant) are read
    back from Mitsuba once per phase function: a second frame of the same
    one launches no kernel for them; changing g gives a new table, equal to
    Mitsuba's phase function at the new g."""
    import drjit as dr

    from episcatter.kernels import kernel_log
    from integrators.epipolar.kernel.local import phase_table
    from tests.conftest import scene_dict

    scene = mi.load_dict(scene_dict(light="point", phase={"type": "hg", "g": 0.3}))
    s = np.linspace(0.0, 2.0 * np.pi, 9)
    first = phase_table(SceneParams.from_scene(scene))(s)
    params = SceneParams.from_scene(scene)
    with kernel_log() as log:
        again = phase_table(params)(s)
    assert log.launched == 0
    np.testing.assert_array_equal(first, again)
    params = mi.traverse(scene)
    key = next(k for k in params.keys() if k.endswith(".g") or k == "g")
    params[key] = 0.6
    params.update()
    changed = phase_table(SceneParams.from_scene(scene))(s)
    g = 0.6
    cos_t = -np.cos(s)      # θ = π − s between −ω and the direction to the light
    hg = (1 - g * g) / (4 * np.pi * (1 + g * g + 2 * g * cos_t) ** 1.5)
    np.testing.assert_allclose(changed, hg, rtol=1e-4)
    assert not np.allclose(changed, first)
    dr.eval()


@pytest.mark.parametrize("sigma_t", [0.3, {"type": "rgb", "value": [0.2, 0.3, 0.5]}])
def test_point_light_factor_equals_the_sub_ray_mean(sigma_t):
    """A point light's per-light-ray factor is its colour and the
    light-side extinction without asking the light along every sub-ray:
    equal to the sub-ray mean (the spot light's path) to float rounding,
    the same lit sub-rays, and a black light lights none."""
    from integrators.epipolar import local_light_factor as llf
    from integrators.epipolar.light_rays.local import local_light_ray_grid
    light = {"type": "point", "position": [0.3, 1.6, 0.2], "intensity": {"type": "rgb", "value": [3.0, 2.0, 1.0]}}
    params, cap, frame, sl, q = setup(light, sigma_t=sigma_t)
    rays = local_light_ray_grid(params, q, 64)
    fast = llf._point_light_factor(params, q, rays, 4)
    slow = llf._sub_ray_factor(params, q, rays, 4, 0)
    np.testing.assert_allclose(np.array(fast[0]), np.array(slow[0]), rtol=2e-6, atol=0)
    np.testing.assert_allclose(np.array(fast[1]), np.array(slow[1]), rtol=2e-6)
    np.testing.assert_array_equal(np.array(fast[2]), np.array(slow[2]))
    dark = setup({**light, "intensity": 0.0}, sigma_t=sigma_t)
    lit = llf._point_light_factor(dark[0], dark[4], local_light_ray_grid(dark[0], dark[4], 64), 4)[2]
    assert not np.array(lit).any()

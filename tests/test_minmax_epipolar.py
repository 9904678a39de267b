"""minmax_epipolar (Yusov 2013): each kernel against its NumPy oracle, and the
image against ``raymarch visibility=exact`` at pixel centres."""
import math

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter import metrics
from integrators.core.capture import capture_camera
from integrators.core.scene_params import SceneParams
from integrators.epipolar.frame import epipolar_frame_of
from integrators.minmax import light_rays as lr
from integrators.minmax import minmax_tree as mt
from integrators.minmax import refinement as rf
from integrators.minmax import section_integral as si
from integrators.minmax import slices_and_samples as ss
from integrators.minmax.profiles import profile_settings


HG = {"type": "hg", "g": 0.6}


def params_of(make_scene, **kw):
    return SceneParams.from_scene(make_scene(**kw))


def np3(c):
    return np.stack([np.asarray(c[i], dtype=np.float64) for i in range(3)], axis=-1)


# --------------------------------------------------------------------------
# per-section integrals
# --------------------------------------------------------------------------

@pytest.mark.parametrize("sigma_t", [1e-5, 0.3, 3.0])
def test_directional_section_matches_quadrature(make_scene, sigma_t):
    p = params_of(make_scene, sigma_t=sigma_t)
    rng = np.random.default_rng(0)
    o = np.asarray(p.camera.origin)
    for _ in range(12):
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        with np.errstate(divide="ignore"):
            t_exit = np.min(np.maximum((p.medium.bounds_min - o) / w, (p.medium.bounds_max - o) / w))
        t_a, t_b = sorted(rng.uniform(0.0, t_exit, 2))     # camera rays stay in the box
        ref = si.directional_section_reference(p.medium.sigma_t, o, w, p.light.direction,
                                               p.medium.bounds_min, p.medium.bounds_max, t_a, t_b)
        path = si.box_path(p, mi.Point3f(*map(float, o)), mi.Vector3f(*map(float, w)))
        got = np3(si.directional_section(si.sigma_colour(p), path, mi.Float(t_a), mi.Float(t_b)))[0]
        assert np.allclose(got, ref, rtol=2e-4, atol=1e-7 * (t_b - t_a + 1e-9))


def test_exp_segment_handles_negative_and_tiny_rates():
    for k in (-3.0, -1e-6, 0.0, 1e-6, 5.0):
        got = float(si.exp_segment(mi.Float(k), mi.Float(0.5), mi.Float(2.0))[0])
        ref = (math.exp(-k * 0.5) - math.exp(-k * 2.0)) / k if k else 1.5
        assert got == pytest.approx(ref, rel=1e-5)


@pytest.mark.parametrize("light,phase", [("point", None), ("spot", HG)])
def test_point_table_error_is_bounded(make_scene, light, phase):
    """Two table reads against Simpson quadrature of the section integral:
    the relative error stays below 2e-3 at 256 nodes per axis and shrinks
    with the resolution."""
    p = params_of(make_scene, light=light, phase=phase)
    rng = np.random.default_rng(1)
    o = np.asarray(p.camera.origin)
    cases = []
    for _ in range(16):
        w = rng.normal(size=3)
        w /= np.linalg.norm(w)
        cases.append((w, *sorted(rng.uniform(0.0, 4.0, 2))))
    worst = {}
    for res in (64, 256):
        table = si.point_table(p, res)
        errs = []
        for w, t_a, t_b in cases:
            ref = si.point_section_reference(p, o, w, t_a, t_b)
            ray = si.point_ray(p, mi.Point3f(*map(float, o)), mi.Vector3f(*map(float, w)))
            got = np3(si.point_section(si.sigma_colour(p), table, ray, mi.Float(t_a),
                                       mi.Float(t_b)))[0]
            errs.append(np.abs(got - ref).max() / max(ref.max(), 1e-12))
        worst[res] = max(errs)
    assert worst[256] < 2e-3
    assert worst[256] < worst[64]


def test_point_table_matches_its_definition(make_scene):
    """C(h, φ) against direct quadrature at a few nodes."""
    p = params_of(make_scene, light="point", phase=HG, sigma_t=1.0)
    h = np.array([0.0, 0.7, 3.0])
    phi = np.array([-1.2, 0.0, 0.9])
    table = si.point_table_reference(p, h, phi)
    for i, hi in enumerate(h):
        for j, ph in enumerate(phi):
            x = np.linspace(ph, math.pi / 2, 200001)[:-1]
            P = si.phase_of_phi_numpy(p, x)[:, 0]
            f = P * np.exp(-1.0 * hi * (np.tan(x) + 1 / np.cos(x)))
            ref = np.trapezoid(f, x)
            assert table[i, j, 0] == pytest.approx(ref, rel=5e-4, abs=1e-7)


# --------------------------------------------------------------------------
# min/max tree: build and traversal against the per-texel march
# --------------------------------------------------------------------------

def random_height_map(rng, S, n, lo, hi, runs=True):
    z = rng.uniform(lo, hi, (S, n))
    if runs:   # runs of equal depths, gaps without blockers, a blocker at the light
        for k in range(S):
            cut = np.sort(rng.choice(np.arange(1, n), size=min(n - 1, 6), replace=False))
            for a, b in zip(np.r_[0, cut], np.r_[cut, n]):
                z[k, a:b] = rng.choice([rng.uniform(lo, hi), np.inf, lo - 1.0], p=[0.7, 0.2, 0.1])
    return z


@pytest.mark.parametrize("colours", ["random", "panes", "rim"])
@pytest.mark.parametrize("n", [16, 32, 128, 2048])
def test_tree_build_matches_reference(colours, n):
    """Every level, colour state and drop against the NumPy twin; sizes of
    one, two and three of ``build_tree``'s kernel blocks."""
    rng = np.random.default_rng(2 + n)
    S = 3
    z = random_height_map(rng, S, n, 0.0, 1.0)
    colour = rng.integers(0, 3, (S, n, 3)).astype(np.float64) if colours == "random" \
        else texel_colours(rng, S, n, colours)
    rays = fake_light_rays(z, z, colour, np.zeros(S), np.full(S, 0.1))
    tree = mt.build_tree(rays)
    ref = mt.build_tree_reference(z, z, colour)
    zmin, zmax, state = np.asarray(tree.z_min), np.asarray(tree.z_max), np.asarray(tree.state)
    assert tree.constant_colour is None
    for level, (a, b, c, d) in enumerate(ref):
        off = mt.MinMaxTree.offset(n, level)
        m = n >> level
        sl = (np.arange(S)[:, None] * 2 * n + off + np.arange(m)[None]).ravel()
        assert np.array_equal(zmin[sl].reshape(S, m), a.astype(np.float32))
        assert np.array_equal(zmax[sl].reshape(S, m), b.astype(np.float32))
        assert np.array_equal(state[sl].reshape(S, m), mt.colour_state_reference(c, d))
    states = [mt.colour_state_reference(c, d) for _, _, c, d in ref]
    drop = np.asarray(tree.drop)
    for level, d in enumerate(mt.drop_reference(states)):
        off, m = mt.MinMaxTree.offset(n, level), n >> level
        sl = (np.arange(S)[:, None] * 2 * n + off + np.arange(m)[None]).ravel()
        assert np.array_equal(drop[sl].reshape(S, m), d), level


def test_overflowed_light_colour_is_not_a_constant_colour():
    """A light outside the box in thick fog overflows some texels' entry
    factor to inf (stress case "point near the face"): that is no one-colour
    light, else the image turns NaN."""
    colour = mi.Color3f(mi.Float([1e8, np.inf]), mi.Float([1e8, np.inf]), mi.Float([1e8, np.inf]))
    assert mt.constant_colour(colour) is None


def test_tree_of_a_one_colour_light_stores_no_colours():
    rng = np.random.default_rng(5)
    z = random_height_map(rng, 2, 16, 0.0, 1.0)
    rays = fake_light_rays(z, z, np.full((2, 16, 3), 0.5), np.zeros(2), np.full(2, 0.1))
    tree = mt.build_tree(rays)
    assert tree.state is None and tree.constant_colour == pytest.approx((0.5, 0.5, 0.5))
    ref = mt.build_tree_reference(z, z, np.full((2, 16, 3), 0.5))
    assert np.array_equal(np.asarray(tree.z_min)[2 * 16 - 2:2 * 16 - 1], ref[-1][0][0].astype(np.float32))


def fake_light_rays(z_min, z_max, colour, gamma_lo, delta, u_top=0.0, bias=0.0):
    S, n = z_min.shape
    c = colour.reshape(S * n, 3).astype(np.float32)
    return lr.SliceLightRays(n=n, gamma_lo=np.asarray(gamma_lo, np.float64),
                             delta=np.asarray(delta, np.float64), u_top=u_top, bias=bias,
                             z_min=mi.Float(z_min.ravel().astype(np.float32)),
                             z_max=mi.Float(z_max.ravel().astype(np.float32)),
                             colour=mi.Color3f(c[:, 0], c[:, 1], c[:, 2]))


def moments(a, b):
    """A section 'integral' that tells intervals apart: (Δt, Δt², Δt³)."""
    return mi.Color3f(b - a, b * b - a * a, b * b * b - a * a * a)


def moments_np(a, b):
    return np.array([b - a, b * b - a * a, b ** 3 - a ** 3])


def texel_colours(rng, S, n, textured):
    """Light colours per texel: white; panes of 8 texels (some black); or a
    spot's fall-off rim — a ramp, every texel its own colour — over panes of
    16 (issue 14: lit runs of mixed colour)."""
    if not textured:
        return np.ones((S, n, 3))
    panes = np.repeat(rng.integers(0, 3, (S, n // 8, 3)), 8, axis=1).astype(np.float64)
    if textured == "panes":
        return panes
    ramp = np.linspace(0.1, 1.0, n)[None, :, None] * np.ones((S, 1, 3))
    rim = np.arange(n) < n // 3
    return np.where(rim[None, :, None], ramp, np.repeat(panes[:, ::2], 2, axis=1))


@pytest.mark.parametrize("light", ["directional", "point"])
@pytest.mark.parametrize("textured", [None, "panes", "rim"])
def test_traversal_equals_per_texel_march(make_scene, light, textured):
    """The tree's sections are unions of the per-texel march's lit texels:
    identical integrals (to float32 rounding) for random height maps with
    runs, blocker-free gaps and blockers at the light, rays clipped at the
    γ range's start (spot cone), zero-length rays and rays inside one texel;
    light colours white, in panes, or a ramp (lit runs of mixed colour)."""
    p = params_of(make_scene, light=light)
    frame = epipolar_frame_of(p)
    rng = np.random.default_rng(3 + bool(textured))
    S, n, R = 4, 64, 72
    k = rng.integers(0, S, R)
    beta = rng.uniform(0.05, math.pi - 0.6, R)
    beta[:4] = [1e-4, 0.02, math.pi - 0.7, 1.0]
    t_end = rng.uniform(0.0, 3.0, R)
    t_end[4:8] = [0.0, 1e-4, 1e-3, 3.0]
    t_near = np.full(R, 0.01)
    alpha = rng.uniform(-math.pi, math.pi, S)
    g_max = np.zeros(S)
    from rectify import view_to_light_reference
    g_end = np.array([view_to_light_reference(frame, alpha[k[r]], beta[r], t_near[r] + t_end[r])[0]
                      for r in range(R)])
    for s in range(S):
        g_max[s] = max(g_end[k == s].max(initial=0.0), 1e-3) * 1.01
    gamma_lo = np.where(np.arange(S) == 0, 0.3 * g_max, 0.0)     # slice 0: clipped start
    delta = (g_max - gamma_lo) / n
    u_top = 5.0 if light == "directional" else 0.0
    depth_lo, depth_hi = (u_top - 3.0, u_top + 3.0) if light == "directional" else (0.0, 6.0)
    z = random_height_map(rng, S, n, depth_lo, depth_hi)
    colour = texel_colours(rng, S, n, textured)
    rays = fake_light_rays(z, z, colour, gamma_lo, delta, u_top=u_top, bias=1e-4)
    tree = mt.build_tree(rays)
    srays = mt.SliceRays(k=mi.UInt32(k.astype(np.uint32)), beta=mi.Float(beta.astype(np.float32)),
                         t_near=mi.Float(t_near.astype(np.float32)),
                         t_end=mi.Float(t_end.astype(np.float32)),
                         alpha=mi.Float(alpha[k].astype(np.float32)))
    full = mt.march_tree(frame, rays, tree, srays, moments)
    flat = mt.march_tree(frame, rays, tree, srays, moments, max_level=0)
    L_full, L_flat = np3(full.L), np3(flat.L)
    scale = np.abs(L_flat).max(axis=0) + 1e-12
    assert np.all(np.abs(L_full - L_flat) <= 2e-5 * scale)
    assert np.asarray(full.steps).sum() < np.asarray(flat.steps).sum()
    for r in range(R):
        ref, _ = mt.march_texels_reference(
            frame, z[k[r]].astype(np.float32).astype(np.float64), colour[k[r]],
            float(np.float32(gamma_lo[k[r]])), float(np.float32(delta[k[r]])), u_top, 1e-4,
            float(np.float32(beta[r])), float(np.float32(t_near[r])), float(np.float32(t_end[r])),
            moments_np, alpha=float(np.float32(alpha[k[r]])))
        assert np.allclose(L_flat[r], ref, rtol=1e-3, atol=2e-4 * scale.max()), r


def lit_ramp_march(make_scene, tally=False):
    """Point light, one slice of n = 256 texels without blockers and a ramp
    of light colours (every texel its own): rays that cross many texels."""
    p = params_of(make_scene, light="point")
    frame = epipolar_frame_of(p)
    n, R = 256, 16
    z = np.full((1, n), np.inf)
    colour = np.linspace(0.1, 1.0, n)[None, :, None] * np.ones((1, n, 3))
    beta = np.linspace(0.3, 2.0, R)
    from rectify import view_to_light_reference
    t_end = np.full(R, 3.0)
    g_max = max(view_to_light_reference(frame, 0.0, b, 0.01 + 3.0)[0] for b in beta) * 1.01
    rays = fake_light_rays(z, z, colour, [0.0], [g_max / n])
    srays = mt.SliceRays(k=mi.UInt32(np.zeros(R, np.uint32)), beta=mi.Float(beta.astype(np.float32)),
                         t_near=mi.Float(np.full(R, 0.01, np.float32)),
                         t_end=mi.Float(t_end.astype(np.float32)),
                         alpha=mi.Float(np.zeros(R, np.float32)))
    tree = mt.build_tree(rays)
    return (mt.march_tree(frame, rays, tree, srays, moments, tally=tally),
            mt.march_tree(frame, rays, tree, srays, moments, max_level=0))


def test_lit_run_of_mixed_colour_costs_one_step_per_texel(make_scene):
    """A lit node of mixed colour is split once, dropping straight to the
    leaf (``MinMaxTree.drop``): its texels are then marched at level 0
    without climbing back into mixed nodes (issue 14: the spot's fall-off
    rim cost ~1.5 steps per texel), the integral the per-texel march's (its
    own oracle-tested sum)."""
    full, flat = lit_ramp_march(make_scene)
    L_full, L_flat = np3(full.L), np3(flat.L)
    assert np.all(np.abs(L_full - L_flat) <= 2e-5 * (np.abs(L_flat).max(axis=0) + 1e-12))
    texels, steps = np.asarray(flat.steps), np.asarray(full.steps)
    assert np.all(texels > 20)
    assert np.all(steps <= texels + 2)                  # the split, dropping to the leaf


def test_step_tally_counts_every_step(make_scene):
    """``tally``: the steps of each kind add up to the steps; a blocker-free
    ramp has only lit steps and colour splits."""
    full, _ = lit_ramp_march(make_scene, tally=True)
    t = {k: np.asarray(v) for k, v in full.tally.items()}
    assert set(t) == set(mt.STEP_KINDS)
    assert np.array_equal(sum(t.values()), np.asarray(full.steps))
    assert all(t[k].sum() == 0 for k in ("dark_node", "dark_leaf", "black", "boundary_split",
                                         "boundary_leaf"))
    assert t["lit_leaf"].sum() > 0 and t["colour_split"].sum() > 0


# --------------------------------------------------------------------------
# slices, samples, refinement
# --------------------------------------------------------------------------

def test_samples_rescaled_to_one_per_pixel(make_scene):
    p = params_of(make_scene, res=(48, 36))
    s = ss.epipolar_samples(p, "auto", 400)
    on = s.on_screen_count
    assert on.max() <= 48 + 36 + ss.EXTRA_SAMPLES + 1     # ~1 sample per pixel, not 400
    d = np.asarray(s.d)
    used = np.asarray(s.used)
    assert np.all(np.isfinite(d[used])) and np.all(d[used] > 0)


def test_interpolation_sources_match_direct_scan(make_scene):
    p = params_of(make_scene, res=(40, 30))
    s = ss.epipolar_samples(p, 24, 40)
    for step in (1, 5, 16):
        flags = rf.initial_samples(s, step) | rf.depth_breaks(s, 0.03, "relative")
        src = rf.interpolation_sources(s, flags)
        S, M = s.slices.count, s.count
        lo, hi, f = rf.interpolation_sources_reference(np.asarray(s.used).reshape(S, M),
                                                       np.asarray(flags).reshape(S, M))
        used = np.asarray(s.used)
        assert np.array_equal(np.asarray(src.lo)[used], lo.ravel()[used])
        assert np.array_equal(np.asarray(src.hi)[used], hi.ravel()[used])
        assert np.allclose(np.asarray(src.f)[used], f.ravel()[used], atol=1e-6)


@pytest.mark.parametrize("step", [1, 4, 16])
def test_visibility_refinement_matches_the_rule_round_by_round(make_scene, step):
    """``integrate_refined`` (the halves of the last round's splits alone,
    the slices' peaks on the device) integrates exactly the samples of the
    rule checking every interval every round; values of edges, dark
    stretches (the floor) and a bright spike that raises a slice's peak
    late."""
    p = params_of(make_scene, res=(40, 30))
    s = ss.epipolar_samples(p, 24, 40)
    S, M = s.slices.count, s.count
    rng = np.random.default_rng(step)
    j = np.arange(M)[None, :]
    edges = rng.integers(0, M, (S, 3))
    field = (1.0 + (j > edges[:, :1]) * 3.0 - (j > edges[:, 1:2]) * 3.9) * np.exp(-0.05 * j)
    field[:, 5] += 40.0 * (rng.random(S) < 0.3)
    field = np.maximum(field, 0.0).astype(np.float32)
    lum = mi.Float(field.ravel())
    flags = rf.initial_samples(s, step)

    def integrate(lanes):
        v = dr.gather(mi.Float, lum, lanes)
        return mi.Color3f(v, v, v), dr.full(mi.UInt32, 2, dr.width(lanes))

    done = rf.integrate_refined(s, flags, integrate, 0.1, True)
    used = np.asarray(s.used).reshape(S, M)
    ref = rf.visibility_refinement_reference(used, np.asarray(flags).reshape(S, M),
                                             field, 0.1)
    got = np.asarray(done.flags).reshape(S, M)
    assert np.array_equal(got, ref)
    assert done.count == ref.sum() and int(done.steps[0]) == 2 * ref.sum()
    values = np.asarray(done.values.x).reshape(S, M)
    assert np.array_equal(values[ref], field[ref]) and not values[~ref].any()
    assert step == 1 or ref.sum() > np.asarray(flags).sum()     # the rule refined something
    once = rf.integrate_refined(s, flags, integrate, 0.1, False)
    assert np.array_equal(np.asarray(once.flags), np.asarray(flags)) and once.rounds == 1


def test_depth_breaks_match_direct_scan(make_scene):
    p = params_of(make_scene, res=(40, 30))
    s = ss.epipolar_samples(p, 24, 40)
    S, M = s.slices.count, s.count
    d = np.asarray(s.d).reshape(S, M)
    used = np.asarray(s.used).reshape(S, M)
    for mode, thr in (("relative", 0.05), ("absolute", 0.2)):
        got = np.asarray(rf.depth_breaks(s, thr, mode)).reshape(S, M)
        ref = np.zeros((S, M), bool)
        for k in range(S):
            for j in range(M - 1):
                if used[k, j] and used[k, j + 1]:
                    lim = thr if mode == "absolute" else thr * min(d[k, j], d[k, j + 1])
                    if abs(np.float32(d[k, j]) - np.float32(d[k, j + 1])) > np.float32(lim):
                        ref[k, j] = ref[k, j + 1] = True
        assert np.array_equal(got, ref)


@pytest.mark.parametrize("sigma", [0.03, 0.1, 1e-4])
@pytest.mark.parametrize("light", ["directional", "point"])
def test_unwarp_weights_match_direct_formula(make_scene, sigma, light):
    from integrators.minmax.unwarp import unwarp
    from rectify import unrectify_bilateral_reference
    p = params_of(make_scene, res=(24, 18), light=light)
    s = ss.epipolar_samples(p, "auto", 24)
    S, M = s.slices.count, s.count
    rng = np.random.default_rng(5)
    values = rng.uniform(0, 1, (S, M, 3))
    sd = np.asarray(s.d).reshape(S, M)
    cap = capture_camera(p, surface=False)
    pd = np.asarray(cap.d).reshape(18, 24)
    v = values.reshape(-1, 3).astype(np.float32)
    img, w = unwarp(s, mi.Color3f(v[:, 0], v[:, 1], v[:, 2]), cap.d, sigma)
    img_r, w_r = unrectify_bilateral_reference(s.frame, s.slices, s.grid, values, sd, pd, sigma)
    assert np.allclose(np.asarray(w), w_r.ravel(), atol=1e-4)
    err = np.abs(np3(img) - img_r.reshape(-1, 3)).max()
    assert err < 5e-4, err          # float32 angles and depths in steep weights


def test_profiles_follow_the_talk():
    assert profile_settings("high_quality", 2560, 1600) == dict(
        slices=2048, samples=1024, shadowmap_resolution=4096, light_rays=4096)
    assert profile_settings("high_performance", 1366, 768)["samples"] == 256
    assert profile_settings("balanced", 1024, 768)["slices"] == 512


# --------------------------------------------------------------------------
# images
# --------------------------------------------------------------------------

def render(scene, **props):
    """minmax_epipolar's epipolar pipeline (the test images are small
    enough that the defaults would march every pixel instead)."""
    integ = mi.load_dict({"type": "minmax_epipolar", "output": "scattering",
                          "small_image_march": False, **props})
    result = integ.render_layers(scene, spp=1)
    return np.asarray(result["scattering"]), result


def exact(scene):
    return np.asarray(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 1024,
                                    "output": "scattering"}).render(scene))


FINE = dict(initial_step=1, sample_density=4.0, samples=400, light_rays=1024)
COARSE = dict(initial_step=1, light_rays=64)


@pytest.mark.slow
@pytest.mark.parametrize("light,phase", [("directional", None), ("directional", HG),
                                         ("spot_textured", None), ("point", HG)])
def test_converges_to_exact_raymarch(make_scene, light, phase):
    scene = make_scene(light=light, phase=phase, res=(48, 36))
    ref = exact(scene)
    fine, _ = render(scene, **FINE)
    coarse, _ = render(scene, **COARSE)
    e_fine = metrics.scale_free_relmse(fine, ref)
    e_coarse = metrics.scale_free_relmse(coarse, ref)
    assert e_fine < 2e-3, e_fine
    assert e_fine <= e_coarse
    assert abs(metrics.mean_ratio(fine, ref) - 1) < 0.02


def test_default_render_is_close_and_reports_stats(make_scene):
    scene = make_scene(light="spot_textured", res=(32, 24))
    img, integ = render(scene)
    ref = exact(scene)
    assert np.all(np.isfinite(img))
    assert metrics.scale_free_relmse(img, ref) < 5e-2
    st = integ.stats
    assert 0 < st["integration_samples"] <= st["used_samples"]
    assert st["fixup_pixels"] >= 0
    for stage in ("samples", "refinement", "blockers", "tree", "integrate", "unwarp", "fixup"):
        assert stage in integ.timings


@pytest.mark.parametrize("criterion", ["depth", "inscattering", "visibility"])
def test_refinement_criteria_render(make_scene, criterion):
    scene = make_scene(res=(32, 24))
    img, integ = render(scene, refinement=criterion)
    ref = exact(scene)
    assert np.all(np.isfinite(img))
    assert metrics.scale_free_relmse(img, ref) < 5e-2
    base, b = render(scene, refinement="depth")
    if criterion == "visibility":
        assert integ.stats["integration_samples"] >= b.stats["integration_samples"]


def test_resampled_source_renders(make_scene):
    scene = make_scene(light="directional", res=(32, 24))
    img, _ = render(scene, blockers="resampled", shadowmap_resolution=256)
    ref = exact(scene)
    assert np.all(np.isfinite(img))
    assert metrics.scale_free_relmse(img, ref) < 5e-2


def test_tree_off_gives_the_same_image(make_scene):
    scene = make_scene(light="point", res=(32, 24))
    on, a = render(scene)
    off, b = render(scene, min_max=False)
    assert np.allclose(on, off, rtol=1e-4, atol=1e-6 * on.max())
    assert a.stats["mean_steps"] < b.stats["mean_steps"]


@pytest.mark.slow
def test_no_nan_on_stress_cases():
    from experiments import stability as st
    s = st.settings_for(False)
    s.update(res=(32, 24), sigma_t=[1e-4, 10.0, 100.0], scales=[0.01, 1e4],
             grazing_sigma_t=[10.0])
    cases = st.all_cases(s)
    for case in cases:
        scene = mi.load_dict(st.stress_scene(case["light"], case["sigma_t"], case["scale"],
                                             s["res"], camera=case.get("camera")))
        img, _ = render(scene)
        assert np.all(np.isfinite(img)), case["case"]


@pytest.mark.parametrize("props,match", [
    ({"samples_per_pixel": 4}, "one sample per pixel"),
    ({"light_rays": 100}, "power of two"),
    ({"refinement": "magic"}, "refinement"),
    ({"profile": "ultra"}, "profile"),
    ({"blockers": "bent"}, "blockers"),
])
def test_clear_value_errors(make_scene, props, match):
    scene = make_scene(res=(16, 12))
    with pytest.raises((ValueError, RuntimeError)) as err:
        integ = mi.load_dict({"type": "minmax_epipolar", **props})
        integ.render(scene)
    text = str(err.value) + str(getattr(err.value, "__cause__", ""))
    assert match in text


def test_unsupported_scene_gives_the_shared_error(make_scene):
    scene = make_scene(light={"type": "constant"}, res=(16, 12))
    errors = []
    for kind in ("raymarch", "minmax_epipolar"):
        with pytest.raises(Exception) as err:
            mi.load_dict({"type": kind}).render(scene)
        cause = err.value.__cause__ or err.value
        errors.append(str(cause))
    assert errors[0] == errors[1]


@pytest.mark.slow
@pytest.mark.parametrize("name", ["minmax_performance", "minmax_tree_gain", "minmax_quality",
                                  "minmax_speedup"])
def test_experiments_quick(tmp_path, cache, name):
    import importlib
    module = importlib.import_module(f"experiments.{name}")
    module.main(["--quick", "--out", str(tmp_path)])
    for f in ("runs.csv", "runs.json", "table.md"):
        assert (tmp_path / f).is_file()


def test_quality_experiment_counts_integration_samples_and_fixups(make_scene):
    """Issue 14 item 4 asks for the integration samples and fix-up pixels of
    each refinement criterion: they travel in the render's
    ``RenderResult.stats`` (experiments.minmax_quality read a stale
    integrator attribute and printed '-')."""
    from experiments import minmax_quality as mq
    scene = make_scene(res=(24, 18))
    img, counts = mq.render_with_counts(mi.load_dict({"type": "minmax_epipolar",
                                                      "small_image_march": False,
                                                      "output": "full"}), scene)
    assert img.shape == (18, 24, 3) and np.isfinite(img).all()
    assert set(counts) == {"integration_samples", "used_samples", "fixup_pixels"}
    assert 0 < counts["integration_samples"] <= counts["used_samples"]
    assert counts["fixup_pixels"] >= 0
    _, none = mq.render_with_counts(mi.load_dict({"type": "raymarch", "output": "full"}), scene)
    assert none == {}


def test_performance_sizes_are_the_talks(tmp_path, cache):
    """``--sizes`` takes only the talk's table sizes (a clear error names
    them); with ``--no-directional`` only those spot tables are run."""
    import argparse

    from experiments import minmax_performance as mp
    assert mp.talk_size("1024x768") == (1024, 768)
    with pytest.raises(argparse.ArgumentTypeError, match="1366x768"):
        mp.talk_size("1000x700")
    rows = mp.main(["--quick", "--sizes", "1024x768", "--no-directional", "--out",
                    str(tmp_path)])
    assert rows and {r["talk_size"] for r in rows} == {"1024x768"}


@pytest.mark.parametrize("light", ["directional", "spot"])
def test_resampled_tree_never_changes_the_per_texel_march(make_scene, light):
    """Conservative 2×2-filter bounds: the tree gives the per-texel PCF
    march's image (to float32 rounding and, for the spot, to the table's
    section error)."""
    scene = make_scene(light=light, res=(32, 24))
    props = dict(blockers="resampled", shadowmap_resolution=128, light_rays=512)
    on, a = render(scene, **props)
    off, b = render(scene, min_max=False, **props)
    assert np.allclose(on, off, rtol=2e-3, atol=2e-3 * off.max())
    assert a.stats["mean_steps"] < b.stats["mean_steps"]


def test_explicit_properties_override_the_profile(make_scene):
    p = params_of(make_scene, res=(1366, 768))
    integ = mi.load_dict({"type": "minmax_epipolar", "profile": "balanced", "samples": 77})
    s = integ.settings(p)
    assert s == dict(slices=512, samples=77, light_rays=1024, shadowmap_resolution=1024)


def test_step_budget_adds_up_to_the_renders_mean_steps(make_scene):
    """``experiments.minmax_step_budget``: the kinds' mean steps per
    integration sample add up to the render's own ``mean_steps``."""
    from experiments.minmax_step_budget import tallied_render
    scene = make_scene(light="spot_textured", res=(32, 24))
    integ = mi.load_dict({"type": "minmax_epipolar", "small_image_march": False})
    budget = tallied_render(scene, integ)
    stats = integ.render_layers(scene, spp=1).stats
    assert set(budget) == set(mt.STEP_KINDS)
    assert sum(budget.values()) == pytest.approx(stats["mean_steps"], rel=1e-6)
    assert budget["colour_split"] + budget["lit_leaf"] > 0

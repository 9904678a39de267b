"""SVD separation of the integrand (Baran et al. 2010, §6, Eq. 4)."""
import numpy as np
import pytest

from integrators.epipolar.kernel.svd import (choose_rank, directional_light_kernel,
                                             relative_error, sample_grid, sample_integrand,
                                             separate_integrand, truncation_errors)


def hg(beta, g=0.6):
    """Henyey-Greenstein of the scattering angle β (light → camera)."""
    return (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * np.cos(beta)) ** 1.5)


def integration_grid(gamma_max=20.0, d=1024, r=512, ring_deg=2.0):
    """Light-ray centres and view-ray angles, a 2° ring around the epipole
    (β = 0) and the anti-epipole excluded (§6)."""
    gamma = (np.arange(d) + 0.5) * gamma_max / d
    beta = np.linspace(np.radians(ring_deg), np.radians(180 - ring_deg), r)
    return gamma, beta


def test_directional_kernel_is_the_attenuated_path():
    """DESIGN §1: e^{-σt t} e^{σt u} with t = γ / sin β, u = γ cot β equals
    e^{-σt γ tan(β/2)}; with dt/dγ = 1/sin β that is the kernel."""
    sigma_t = 0.7
    gamma, beta = np.meshgrid(np.linspace(0, 5, 9), np.linspace(0.1, 3.0, 7), indexing="ij")
    t, u = gamma / np.sin(beta), gamma / np.tan(beta)
    direct = np.exp(-sigma_t * t) * np.exp(sigma_t * u) / np.sin(beta)
    np.testing.assert_allclose(directional_light_kernel(sigma_t)(gamma, beta), direct,
                               rtol=1e-12)


@pytest.mark.parametrize("sigma_t, gamma_max", [(0.5, 20.0), (0.1, 5.0), (2.0, 3.0)])
def test_error_falls_as_N_grows(sigma_t, gamma_max):
    I = directional_light_kernel(sigma_t, hg)
    gamma, beta = integration_grid(gamma_max)
    seps = [separate_integrand(I, gamma, beta, N=N) for N in range(1, 7)]
    grid = [s.grid_error for s in seps]
    full = [s.error for s in seps]
    assert all(b < a for a, b in zip(grid, grid[1:]))
    assert all(b < a for a, b in zip(full, full[1:]))
    assert [s.N for s in seps] == list(range(1, 7))
    assert seps[0].A.shape == (1024, 1) and seps[-1].B.shape == (512, 6)


@pytest.mark.parametrize("tol", [1e-2, 1e-3, 1e-4])
def test_chosen_N_meets_the_tolerance(tol):
    I = directional_light_kernel(0.5, hg)
    gamma, beta = integration_grid()
    sep = separate_integrand(I, gamma, beta, tol=tol)
    assert sep.grid_error <= tol and sep.error <= tol
    if sep.N > 1:   # N is the smallest such rank
        smaller = separate_integrand(I, gamma, beta, N=sep.N - 1)
        assert smaller.grid_error > tol or smaller.error > tol
    # ``error`` is measured on a subset of the coordinates; all of them agree.
    assert relative_error(I, sep.A, sep.B, gamma, beta) <= 1.5 * tol


def test_exactly_separable_integrand():
    def I(g, b):
        return np.exp(-g) * np.cos(b) + g ** 2 * np.sin(3 * b)
    gamma, beta = np.linspace(0, 2, 300), np.linspace(0, 1, 200)
    sep = separate_integrand(I, gamma, beta, tol=1e-9)
    assert sep.N == 2
    assert relative_error(I, sep.A, sep.B, gamma, beta) < 1e-12
    assert (sep.A.sum(0) >= 0).all()                   # deterministic signs


def test_linear_upsampling_as_in_the_paper():
    """§6: on the grid itself A Bᵀ is the truncated SVD; between grid points
    linear upsampling is good for a smooth kernel, poor near the epipole."""
    I = directional_light_kernel(0.5, hg)
    g_grid, b_grid = sample_grid([0, 10]), sample_grid([0.5, 2.5])
    on_grid = separate_integrand(I, g_grid, b_grid, N=3, extend="linear")
    assert relative_error(I, on_grid.A, on_grid.B, g_grid, b_grid) == pytest.approx(
        on_grid.grid_error, rel=1e-9)
    smooth = separate_integrand(I, np.linspace(0, 10, 1000), np.linspace(0.5, 2.5, 700),
                                N=3, extend="linear")
    assert smooth.error < 5e-3
    gamma, beta = integration_grid()
    near_epipole = separate_integrand(I, gamma, beta, N=4, extend="linear")
    exact = separate_integrand(I, gamma, beta, N=4)
    assert exact.error < near_epipole.error / 10


def test_sampled_matrix_input():
    I = directional_light_kernel(0.3)
    g_grid, b_grid = np.linspace(0, 4, 48), np.linspace(0.3, 2.0, 40)
    M = sample_integrand(I, g_grid, b_grid)
    sep = separate_integrand(M, np.linspace(0, 4, 500), np.linspace(0.3, 2.0, 300),
                             tol=1e-4, grid=(g_grid, b_grid))
    assert sep.error == sep.grid_error <= 1e-4
    assert sep.A.shape == (500, sep.N) and sep.B.shape == (300, sep.N)
    assert relative_error(I, sep.A, sep.B, np.linspace(0, 4, 500),
                          np.linspace(0.3, 2.0, 300)) < 5e-3


def test_rank_selection_helpers():
    sigma = np.array([1.0, 0.1, 0.01, 0.0])
    errors = truncation_errors(sigma)
    assert errors[0] == 1.0 and errors[-1] == 0.0
    np.testing.assert_allclose(errors[1], np.sqrt(0.0101 / 1.0101))
    assert choose_rank(sigma, 0.2) == 1
    assert choose_rank(sigma, 0.05) == 2
    assert choose_rank(sigma, 0.0) == 3
    assert choose_rank(sigma, 0.0, max_N=2) == 2


def test_rank_never_exceeds_numerical_rank():
    gamma, beta = np.linspace(0, 1, 100), np.linspace(0, 1, 80)
    sep = separate_integrand(lambda g, b: 1 + 0 * g * b, gamma, beta, N=5)
    assert sep.N == 1 and sep.error < 1e-12


def test_non_finite_integrand_is_rejected():
    I = directional_light_kernel(0.5)
    with np.errstate(divide="ignore"), pytest.raises(ValueError, match="epipole"):
        separate_integrand(I, np.linspace(0, 1, 10), np.linspace(0.0, 1.0, 10))


def test_separation_feeds_the_tree():
    """End to end: an unshadowed slice integrates Σ_γ I(γ_c, β) Δγ."""
    from integrators.tree.partial_sum_tree import integrate_slices
    d, r, gamma_max = 256, 64, 10.0
    dg = gamma_max / d
    gamma, beta = (np.arange(d) + 0.5) * dg, np.linspace(0.2, 2.8, r)
    I = directional_light_kernel(0.4, hg)
    sep = separate_integrand(I, gamma, beta, tol=1e-5)
    D = np.full((1, r), 200.5, np.float32)
    out = np.array(integrate_slices(D, np.full((1, d), np.inf), sep.A.astype(np.float32),
                                    sep.B.astype(np.float32), delta_gamma=dg))[0]
    Ifull = sample_integrand(I, gamma, beta)
    expected = (Ifull[:200].sum(0) + 0.5 * Ifull[200]) * dg
    np.testing.assert_allclose(out, expected, rtol=1e-3, atol=1e-4 * expected.max())


def test_directional_sum_errors_match_numpy():
    """The sum check of the automatic rank (``DirectionalSeparation.sum_errors``,
    one kernel over the checked light rays) against the same sums in NumPy
    float64: per row, at its first and last query, Σ |K̃ − K|·L over every
    stride-th light ray and Σ K·L, each times the row's weight, the
    largest of the first over the largest of the second."""
    import mitsuba as mi
    from experiments import common as c
    from integrators.epipolar.kernel import separation as sep

    scene = c.load(c.scene_file("sun_behind"), c.resolution(64, 48))
    seen = []
    real = sep.DirectionalSeparation.sum_errors

    def spy(self, params, queries, rays, kernels):
        out = real(self, params, queries, rays, kernels)
        seen.append((params, queries, rays, kernels, out))
        return out

    sep.DirectionalSeparation.sum_errors = spy
    try:
        mi.render(scene, integrator=mi.load_dict({"type": "epipolar_tree"}), spp=1)
    finally:
        sep.DirectionalSeparation.sum_errors = real
    assert seen
    params, q, rays, kernels, got = seen[0]
    n, d = q.n, rays.d
    r_count = np.asarray(q.r_count).astype(np.int64)
    begin = np.cumsum(r_count) - r_count
    stride = max(1, -(-d // sep.SUM_CHECK_RAYS))
    g = np.minimum(np.arange(-(-d // stride)) * stride, d - 1)
    _, gamma_all = rays.positions(0.0)
    gamma_all = np.asarray(gamma_all, np.float64).reshape(n, d)
    h = np.asarray(rays.h, np.float64).reshape(n, d)
    h_ref = np.asarray(rays.h_ref, np.float64)
    dg = np.asarray(rays.delta_gamma, np.float64)
    beta_q = np.asarray(q.beta, np.float64)
    for kern, value in zip(kernels, got):
        st = kern.sigma_t
        a = [np.asarray(t, np.float64).reshape(n, d)
             for t in kern.a_terms(mi.Float(gamma_all.ravel()), n * d)]
        worst = scale = 0.0
        for s in np.flatnonzero(r_count):
            for qi in (begin[s], begin[s] + r_count[s] - 1):
                beta = beta_q[qi]
                tan = np.tan(0.5 * beta)
                b = [float(np.asarray(t)[0])
                     for t in kern.b_terms(mi.Float([np.float32(tan)] * 2), lanes=n)]
                gam = gamma_all[s, g]
                rel = h[s, g] - h_ref[s]
                L = np.where(np.isfinite(rel) & (-st * h[s, g] <= 7.0), np.exp(-st * rel), 0.0)
                approx = sum(a_i[s, g] * b_i for a_i, b_i in zip(a, b))
                exact = np.exp(-st * gam * tan)
                w = (np.exp(-st * (h_ref[s] - h_ref.min())) * dg[s] * stride
                     / max(np.sin(beta), 1e-6))
                worst = max(worst, (np.abs(approx - exact) * L).sum() * w)
                scale = max(scale, (exact * L).sum() * w)
        np.testing.assert_allclose(value, worst / scale, rtol=2e-3, atol=1e-7)
        assert value > 0.0          # a separated kernel's error: a real comparison

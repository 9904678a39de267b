"""Slow, obvious NumPy oracles shared by the integrator tests."""
import numpy as np


def box_exit(p0, w, bounds_min, bounds_max):
    """Distance from points p0 (inside the box) along directions w to the box."""
    with np.errstate(divide="ignore", invalid="ignore"):
        t0, t1 = (bounds_min - p0) / w, (bounds_max - p0) / w
    return np.min(np.maximum(t0, t1), axis=-1)


def henyey_greenstein(g):
    """f_p(cos θ) of the Henyey-Greenstein phase function, θ between the
    view ray and the direction toward the light (g > 0: looking into it)."""
    return lambda cos: (1 - g * g) / (4 * np.pi * (1 + g * g - 2 * g * cos) ** 1.5)


def unshadowed_directional(params, res, samples=100000, phase=1 / (4 * np.pi)):
    """L_scat per pixel centre of an unshadowed directional light in the
    medium box (isotropic phase by default, or ``phase(cos θ)``, e.g.
    :func:`henyey_greenstein`), by midpoint quadrature in float64 of
    ∫ σs f_p E e^{-σt (t + τ(t))} dt along each camera ray from the near plane
    to the box (exact box exits τ).  Returns (H, W, 3)."""
    cam, med, light = params.camera, params.medium, params.light
    ys, xs = np.mgrid[0:res[1], 0:res[0]] + 0.5
    omega = cam.direction(xs.ravel(), ys.ravel())
    omega /= np.linalg.norm(omega, axis=1, keepdims=True)
    o = cam.origin + omega * (cam.near_clip / (omega @ cam.forward))[:, None]
    out = []
    for oi, wi in zip(o, omega):
        d_exit = box_exit(oi, wi, med.bounds_min, med.bounds_max)
        t = (np.arange(samples) + 0.5) / samples * d_exit
        tau = box_exit(oi + t[:, None] * wi, np.broadcast_to(light.direction, (t.size, 3)),
                       med.bounds_min, med.bounds_max)
        f = np.exp(-med.sigma_t[None] * (t + tau)[:, None])
        f_p = phase(float(wi @ light.direction)) if callable(phase) else phase
        out.append(f.mean(0) * d_exit * med.sigma_s * f_p * light.radiance)
    return np.array(out).reshape(res[1], res[0], 3)


def assert_agrees_with_volpath(scene, chunks: int = 16, spp: int = 1024):
    """The exact marcher (256 steps, 256 jittered samples per pixel) against
    Mitsuba's volpath (``max_depth=2``, ``chunks`` × ``spp`` samples with
    distinct seeds), both integrating the pixel footprint: finite, mean
    within 1 %, scale-free relMSE after 4×4 blocks at most twice volpath's
    own noise (from its chunks' variance)."""
    import mitsuba as mi

    from episcatter.metrics import block_average, noise_relmse_from_variance, scale_free_relmse

    vp = mi.load_dict({"type": "volpath", "max_depth": 2})
    runs = [np.array(mi.render(scene, integrator=vp, spp=spp, seed=s)) for s in range(chunks)]
    ref = np.mean(runs, axis=0)
    variance = np.var(runs, axis=0, ddof=1) / len(runs)
    ours = np.array(mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 256,
                                  "samples_per_pixel": 256, "jitter": True})
                    .render_layers(scene)["full"])
    assert np.all(np.isfinite(ours))
    assert abs(ours.mean() / ref.mean() - 1) < 0.01, ours.mean() / ref.mean()
    err = scale_free_relmse(block_average(ours, 4), block_average(ref, 4))
    noise = noise_relmse_from_variance(ref, variance, block=4)
    assert err <= 2 * noise, (err, noise)

r"""Stages of ``fourier_filter`` (Klehm et al. 2014, "Filter-Based Real-Time
Single Scattering using Rectified Shadow Maps", JCGT 3(3)), one module
each, in pipeline order, on the rectification of :mod:`integrators.epipolar`
(queries, light rays, blockers, kernels):

- :mod:`.rows` — rows and texels per row (small images, the projective
  plan, automatic texel counts);
- :mod:`.projective_rays` — the light rays of Klehm's projective
  rectification (§4.2);
- :mod:`.rectified_map` — the rectified shadow map (blocker angle per
  texel), its coverage of each query, the series' reliability;
- :mod:`.basis` — the Fourier basis of a step (§3.1 Eqs. 6-10);
- :mod:`.prefilter` — prefix sums of the basis per row and the filtered
  visibility of a query (§3.3 Listings 1-4);
- :mod:`.references` — reference rays and their kernels
  (``weights="reference_ray"``, §3.2 Eq. 11);
- :mod:`.exact` — the direct visibility sum (``visibility="exact"``);
- :mod:`.tail` — the traced end of each view ray (``trace_ends``);
- :mod:`.sums` — the rectified sums per channel, assembled per query.

The method
----------
Single scattering with volumetric shadows of a directional, point or
spot light (with or without a projected texture) in the homogeneous
medium around the camera, after Klehm et al. 2014:

1. *Rectified shadow map* (§2.2, §4.1): epipolar slices = rows, ``d``
   light rays per slice = texels, each traced with Mitsuba from the
   light (``blockers="traced"``) or read from a classic shadow map
   (``"resampled"``: orthographic, perspective for a spot light of
   cutoff ≤ 60°, else a cube).  The depth constant along a view ray is
   its angle β to the light; a texel holds its blocker's angle β_b
   (view ray β is shadowed there iff β > β_b: Eq. 5's step).  Every
   camera sample is evaluated at its **own** β and depth (it is a query
   of both neighbouring slices, weighted by its position between them,
   or with ``slice_interpolation=false`` of its nearest slice; nothing
   is interpolated back to pixels; samples whose two slices disagree
   are ray-marched, ``remarch_disagreement``).
   See :mod:`integrators.fourier.rectified_map` for the depth mapping
   (``depth_range``).  The rows and texels are either the epipolar
   ones (Baran's sinh slices, ``d`` equal light rays per slice) or
   Klehm's projective map (§4.2, below).
2. *Basis and prefilter* (§3.1 Eqs. 6-10, §3.3 Listings 1-3): the shadow
   test is expanded in ``M`` Fourier coefficients; weighted running
   prefix sums of the basis along every row (normalised, Appendix A).
3. *Per pixel* (Listing 4): ``M`` coefficients of the ray's depth, one
   dot product per lookup, times the weight sum of the texels in front
   of its end point: L_scat = σs f_p E · Δγ/sin β · Σ_γ L(γ) K(γ, β) V.

Directional light: L(γ) = e^{-σt h(α,γ)} the light-side transmittance
per light ray and K(γ, β) = e^{-σt γ tan(β/2)} the camera and light
transmittance kernel (DESIGN §1, :mod:`integrators.epipolar.queries`).

Point and spot lights (Baran §9, :mod:`integrators.epipolar.kernel.local`):
rows are the same slices, texels are light rays at angles γ *at the
light* on one lattice (a spot light's rows start at its cone; narrower
rows use fewer texels of a row of ``d``), and the blocker angle keeps
its meaning (view ray β is shadowed on light ray γ iff β > β_b).  The
per-view-ray factor is σs·Δγ/(L sin β), L = |p_l − o| the light's
distance from the eye (dt/r² = dγ/(L sin β): the 1/r² fall-off costs
nothing); per light ray L(α, γ) = Mitsuba's intensity
(spot fall-off, projected texture: coloured) times e^{-σt (L − r_in)};
the kernel K(γ, β) = e^{-σt (t + r − L)} f_p(β + γ) holds both
transmittances and the phase function, which depends on β + γ.

``weights`` chooses how the weighted sum Σ L K V is obtained:

``average`` (§3.1)
    filter weights L(γ): the average visibility V̄ of Eq. 4/Listing 4
    times the query's own unshadowed sum U(β) = Σ L K(γ, β).  For a
    local light L carries the light's angular contribution (fall-off,
    texture): §3.2's "angular dependency" weights.
``reference_ray`` (§3.2, Eq. 11, Listing 2; default)
    filter weights L(γ) K(γ, β_ref) of one reference ray per slice:
    the bisectrix of the slice's (smallest, largest) transmittance
    decay, or the min-max optimum (``reference``, see
    :func:`~integrators.fourier.rectified_map.reference_angle`); V̄ · U(β).
    For a local light K(γ, β_ref) is the kernel's mean over each
    texel's interval, the reference ray's phase function f_p(β_ref + γ)
    included: the angular dependency of §3.2 of both the light and the
    scattering angle.
``exact`` (beyond the paper)
    K = Σ_n A_n(γ) B_n(β) separated as in ``epipolar_tree`` (SVD,
    ``svd_rank``/``svd_tolerance``); one filter per component with the
    non-negative weights L (A_n + c_n) (c_n: a per-row shift, undone with
    one more filter of weights L), combined with B_n(β) of the query:
    Σ_γ L K V with the query's own kernel, no reference ray.  Linear in
    the filters, so ``clamp`` applies to the combined average.

U(β) uses the same separated kernel (prefix sums of L A_n, no filter).
Rows with no blocker in view take U directly (closed form, no filter).

Where the series is no estimate (beyond the paper; ``exact_fallback``):
a query whose series texels within 2/M of its own depth, and at least
1/8 of the depth range (where the truncated series blurs and rings
about the step) weigh more than twice its filtered sum
-- fog right behind its blocker: in front of a surface seen from its
shadowed side, along a ray grazing an occluder -- takes the exact sum
(:func:`~integrators.fourier.rectified_map.series_unreliable`,
:mod:`integrators.fourier.exact`); ``stats["exact_fallback"]``.  A
query whose unshadowed sum U the separated kernel cannot resolve (U
below a small share of its terms' magnitude: a float32 cancellation in
a thick medium, :func:`~integrators.fourier.sums.unresolved_by_separation`,
the tree's test) has its camera sample ray-marched; ``stats["unresolved"]``.

The end of each view ray (beyond the paper; ``trace_ends``): a sample
reads the blockers of its slice's plane, up to half a slice spacing
from its own ray, and the surface a ray ends on is the blocker of the
light rays around its end; the short run of texels behind the last
change of visibility before the end is traced on the sample's own ray
(:mod:`integrators.fourier.tail`; epipolar slices;
``stats["tail_traced"]``).  The direct sum (``visibility``) takes U from
the query's own kernel too, no separated kernel.

``rectification="projective"`` (Klehm §4.2, directional light):
the matrix of :func:`~rectify.projective.projective_rectification`
maps every slice to a row and every light ray to a texel.  Rows are
equally spaced in its NDC row, i.e. in tan(α − α_mid) (nearly equally
spaced on screen when the epipole is far off it), as many as keep
every pixel centre within half a pixel of a row
(:func:`~rectify.projective.projective_rows`); the camera samples are
queries of their nearest row, each at its own β and depth as above.
Texels are equally spaced in the matrix's column, i.e. in 1/x (x the
distance along the frustum's bisectrix; γ = x/cos φ on a row): the
depth-buffer non-linearity of §4.2, tamed by Klehm's splits (geometric
in x, each its own projective map, ``projective_splits``; texels per
split ∝ √length, :func:`~rectify.projective.projective_columns`),
fitted to the x range of the camera rays.  Texels are therefore
unequally wide: every weight holds the exact integral over its texel
(Eq. 12 with the map's own texel edges: ``reference_ray``
T(start)(1 − T(across)) along the reference ray, ``average`` the
texel width, ``exact`` the Gauss–Legendre integral of the separated
kernel), and the segment between the map's first edge and the camera
ray's origin is taken in closed form with the first texel's
visibility.  It needs more rows as the epipole nears the screen and
has no rasterisation to gain in a ray tracer, hence ``auto`` (below;
its accuracy and time against the epipolar slices:
``results/projective_angles``).  Blockers are traced (or read
from the shadow map) along the light ray through each texel centre.

``visibility`` chooses how the weighted visibility V̄ is obtained:
``filter`` (Klehm's Fourier filter, everything above), ``exact`` (the
direct sum Σ_γ L K(γ, β) V cover over the covered texels with each
query's own kernel, :mod:`integrators.fourier.exact`: no ringing, no
leak into shadowed fog, no weighting error; ``D`` gathers per query
instead of ``2 M`` plus the prefilter), or ``auto`` (default):
``exact``, unless one of the filter's own properties (``coefficients``,
``weights``, ``reference``, ``reference_rays``, ``regions``, ``clamp``,
``fit_depth``, ``exact_bounds``, ``depth_range``) is set, then
``filter`` -- so ``coefficients=32`` reproduces the paper; point and
spot lights take the filter under ``auto`` (the direct sum evaluates
their kernel per texel and query: many times the filter's cost).

``reference_rays`` (filter, ``weights="reference_ray"``): Klehm's single
reference ray per row is right only while the medium is thin across the
row (its kernel e^{-σt γ tan(β/2)} then differs little between the
row's view rays); several reference rays per row, each query's
weights the mix of its two nearest
(:mod:`integrators.fourier.references`), keep the energy in thick
media.  0 (default): automatic per row; 1: the paper's.

Images smaller than 32 px on the long side get finer slices and more
light rays (:mod:`integrators.fourier.rows`).
"""

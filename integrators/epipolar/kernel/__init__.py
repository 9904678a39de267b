"""The separated kernel ``K(γ, β) ≈ Σ aᵢ(γ) bᵢ(β)`` (Baran et al. 2010 Eq. 4,
§6): sampled and SVD'd (:mod:`.svd`), tabulated per light ray
(:mod:`.table`), for a directional light (:mod:`.separation`) and for
point and spot lights (:mod:`.local`).
"""

"""raymarch visibility=exact agrees with volpath max_depth=2 on suite scenes.

The volpath references are shipped in ``references/`` (made by
``python -m experiments.make_shipped_references``: 65,536 spp at 48x36 in
chunks of 1,024 with distinct seeds; each JSON sidecar records spp, seeds,
time and the reference's own noise, estimated per pixel from the 64 chunk
means).  They cover
directional, textured spot and point lights, isotropic and HG g = +0.5/-0.5
phase functions, dark and lit surfaces.  Criteria (foundation issue): image
means within 1 %, and relMSE after 4x4 block averaging (matched pixel
footprint: both sides box-filter each pixel) no larger than twice the
reference's own noise at that block size.
"""
import pytest

from experiments.make_shipped_references import AGREEMENT
from experiments.volpath_agreement import agreement


@pytest.mark.parametrize("stem,defines,spp", AGREEMENT,
                         ids=[f"{s}-{'-'.join(f'{k}{v}' for k, v in d.items())}"
                              for s, d, _ in AGREEMENT])
def test_raymarch_exact_matches_volpath(stem, defines, spp):
    # 16x16 stratified camera samples per pixel and one random step offset
    # per ray: both sides then integrate the pixel footprint and the shafts'
    # edges without aliasing (midpoint steps alias on the nave's 40 m rays)
    r = agreement(stem, defines)
    print(r)
    assert abs(r["mean_ratio"] - 1) < 0.01, r
    assert r["relmse_block4"] <= 2 * r["reference_noise_block4"], r

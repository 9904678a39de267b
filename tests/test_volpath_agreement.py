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
import mitsuba as mi
import numpy as np
import pytest

import scenes
from episcatter.metrics import block_average, noise_relmse_from_variance, scale_free_relmse
from episcatter.reference import SHIPPED_DIR, find_cached_reference, load_reference, load_variance
from episcatter.scene_loading import load_scene
from experiments.make_shipped_references import AGREEMENT

BLOCK = 4


@pytest.mark.parametrize("stem,defines,spp", AGREEMENT,
                         ids=[f"{s}-{'-'.join(f'{k}{v}' for k, v in d.items())}"
                              for s, d, _ in AGREEMENT])
def test_raymarch_exact_matches_volpath(stem, defines, spp):
    path = scenes.path(stem)
    ref_path = find_cached_reference(path, defines, cache_dir=SHIPPED_DIR)
    assert ref_path, ("shipped reference missing: run "
                      "`python -m experiments.make_shipped_references`")
    ref, _ = load_reference(ref_path)
    variance = load_variance(ref_path)
    scene = load_scene(path, defines)
    # 16x16 stratified camera samples per pixel and one random step offset
    # per ray: both sides then integrate the pixel footprint and the shafts'
    # edges without aliasing (midpoint steps alias on the nave's 40 m rays)
    integ = mi.load_dict({"type": "raymarch", "visibility": "exact", "steps": 256,
                          "samples_per_pixel": 256, "jitter": True})
    ours = np.array(integ.render_layers(scene)["full"])
    ratio = ours.mean() / ref.mean()
    assert abs(ratio - 1) < 0.01, ratio
    err = scale_free_relmse(block_average(ours, BLOCK), block_average(ref, BLOCK))
    noise = noise_relmse_from_variance(ref, variance, block=BLOCK)
    assert err <= 2 * noise, (err, noise)

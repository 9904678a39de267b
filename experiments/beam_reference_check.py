"""beam at 1280×960: the 2048-step working reference, `epipolar_tree` at its
defaults and `raymarch visibility=exact steps=256` against a converged
reference (`raymarch visibility=exact steps=1024 boundary_bisections=12`),
scale-free relMSE at the pixel centres, and each against the 2048-step
reference for comparison.  ``python -m experiments.beam_reference_check``
prints one JSON line (results/reference_convergence/beam1280.json)."""
import json

import numpy as np

from experiments import common as c


def main():
    s = {"width": 1280, "height": 960, "reference_steps": c.REFERENCE_STEPS}
    scene, ref, _ = c.scene_with_reference("beam", s, False)
    ref = np.asarray(ref)
    im = {}
    for name, (m, p) in {"bisected1024": ("raymarch", {"visibility": "exact", "steps": 1024, "boundary_bisections": 12}),
                         "tree_defaults": ("epipolar_tree", {}),
                         "raymarch_exact256": ("raymarch", {"visibility": "exact", "steps": 256})}.items():
        im[name] = np.asarray(c.time_renders(scene, {"m": c.build(m, p)}, repeats=1)["m"]["image"])
    conv = im["bisected1024"]
    out = {"scene": "beam", "size": [1280, 960], "against": "raymarch exact steps=1024 boundary_bisections=12"}
    for k, v in [("reference_2048", ref), ("tree_defaults", im["tree_defaults"]), ("raymarch_exact256", im["raymarch_exact256"])]:
        e = c.errors(v, conv, blocks=(1,))
        out[k] = {"relmse": e["relmse_b1"], "max_error_over_peak": e["max_error_over_peak_b1"]}
        e2 = c.errors(v, ref, blocks=(1,)); out[k]["relmse_vs_reference_2048"] = e2["relmse_b1"]
    print(json.dumps(out))


if __name__ == "__main__":
    main()

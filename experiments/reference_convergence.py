"""How far is the old 2048-step exact working reference (raymarch
visibility=exact, midpoint rule), and the bisected one that replaced it
(:func:`episcatter.reference.exact_props`), from converged?  Scale-free
relMSE at the pixel centres, one JSON line per scene.

``python -m experiments.reference_convergence W H scene,scene,...``: it and
4096 steps against 8192 midpoint steps
(results/reference_convergence/s320_2048_vs_8192.jsonl: 320 240, the suite).

``... --against-bisected``: it, ``epipolar_tree`` at its defaults and
``raymarch visibility=exact steps=256`` against ``raymarch visibility=exact
steps=1024 boundary_bisections=12`` (:func:`integrators.core.marching.march_bisected`),
each also against the 2048-step reference
(results/reference_convergence/beam1280.json: 1280 960 beam).

``... --bisected-convergence``: the working reference as it is now
(:func:`episcatter.reference.exact_props`: 2048 steps, 12 bisections) and
the old 2048-step midpoint one against 4096 steps with 16 bisections, with
each one's render time
(results/reference_convergence/s320_bisected_2048_vs_4096.jsonl: 320 240
grove,terrain,beam,nave_offscreen)."""
import argparse
import json

import numpy as np

from experiments import common as c

EXACT = "raymarch"


def image(scene, method, props):
    """One render (no warm-up: nothing is timed)."""
    return np.asarray(c.time_renders(scene, {"m": c.build(method, props)}, repeats=1,
                                     warm_up=False)["m"]["image"])


def relmse(img, ref):
    e = c.errors(img, ref, blocks=(1,))
    return e["relmse_b1"], e["max_error_over_peak_b1"]


def midpoint_2048(scene):
    """The old working reference: 2048 midpoint steps, no bisections."""
    return image(scene, EXACT, {"visibility": "exact", "steps": 2048})


def midpoint_row(name, scene):
    ref = midpoint_2048(scene)
    fine = {st: image(scene, EXACT, {"visibility": "exact", "steps": st}) for st in (4096, 8192)}
    r, m = relmse(ref, fine[8192])
    return {"relmse_2048_vs_8192": r, "max_err_2048": m,
            "relmse_4096_vs_8192": relmse(fine[4096], fine[8192])[0]}


def bisected_row(name, scene):
    ref = midpoint_2048(scene)
    conv = image(scene, EXACT, {"visibility": "exact", "steps": 1024, "boundary_bisections": 12})
    out = {"against": "raymarch exact steps=1024 boundary_bisections=12"}
    tests = {"reference_2048": ref, "tree_defaults": image(scene, "epipolar_tree", {}),
             "raymarch_exact256": image(scene, EXACT, {"visibility": "exact", "steps": 256})}
    for k, v in tests.items():
        r, m = relmse(v, conv)
        out[k] = {"relmse": r, "max_error_over_peak": m,
                  "relmse_vs_reference_2048": relmse(v, ref)[0]}
    return out


def timed_image(scene, props):
    """(image, seconds) of one render (no warm-up)."""
    r = c.time_renders(scene, {"m": c.build(EXACT, props)}, repeats=1, warm_up=False)["m"]
    return np.asarray(r["image"]), r["time_s"]


def bisected_convergence_row(name, scene):
    from episcatter.reference import exact_props

    fine, t_fine = timed_image(scene, {"visibility": "exact", "steps": 4096,
                                       "boundary_bisections": 16})
    now, t_now = timed_image(scene, exact_props(2048))
    old, t_old = timed_image(scene, {"visibility": "exact", "steps": 2048})
    return {"against": "raymarch exact steps=4096 boundary_bisections=16",
            "relmse_bisected_2048x12": relmse(now, fine)[0],
            "relmse_midpoint_2048": relmse(old, fine)[0],
            "seconds": {"bisected_2048x12": t_now, "midpoint_2048": t_old,
                        "bisected_4096x16": t_fine}}


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("width", type=int)
    ap.add_argument("height", type=int)
    ap.add_argument("scenes")
    ap.add_argument("--against-bisected", action="store_true")
    ap.add_argument("--bisected-convergence", action="store_true")
    a = ap.parse_args(argv)
    row = (bisected_convergence_row if a.bisected_convergence
           else bisected_row if a.against_bisected else midpoint_row)
    for name in a.scenes.split(","):
        # every row renders the images it compares: no cached reference needed
        scene = c.load(c.scene_file(name), c.resolution(a.width, a.height))
        print(json.dumps({"scene": name, "size": [a.width, a.height],
                          **row(name, scene)}), flush=True)


if __name__ == "__main__":
    main()

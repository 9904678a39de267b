"""How far is the 2048-step exact working reference (raymarch
visibility=exact, midpoint rule) from converged?  Scale-free relMSE (pixel
centres) of it and of 4096 steps against 8192 steps, per suite scene, one
JSON line each.

``python -m experiments.reference_convergence W H scene,scene,...``
(results/reference_convergence/s320_2048_vs_8192.jsonl: 320 240, the suite)."""
import json
import sys

from experiments import common as c


def main():
    W, H = int(sys.argv[1]), int(sys.argv[2])
    for name in sys.argv[3].split(","):
        s = {"width": W, "height": H, "reference_steps": c.REFERENCE_STEPS}
        scene, ref, _ = c.scene_with_reference(name, s, False)
        out = {}
        for st in (4096, 8192):
            t = c.time_renders(scene, {"m": c.build("raymarch", {"visibility": "exact", "steps": st})}, repeats=1)["m"]
            out[st] = t["image"]
        e1 = c.errors(ref, out[8192], blocks=(1,)); e2 = c.errors(out[4096], out[8192], blocks=(1,))
        print(json.dumps({"scene": name, "size": [W, H], "relmse_2048_vs_8192": e1["relmse_b1"], "max_err_2048": e1["max_error_over_peak_b1"],
                          "relmse_4096_vs_8192": e2["relmse_b1"]}), flush=True)


if __name__ == "__main__":
    main()

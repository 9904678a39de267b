"""Run by tests/test_variants.py in a subprocess: render raymarch,
epipolar_tree and fourier_filter in each variant of argv[1:] (in order, one
process) against the exact marcher and print one line "ROW <json>" per render."""
import json
import sys

import numpy as np

import integrators  # noqa: F401  (registers the plugins for every variant)
import mitsuba as mi

from episcatter.metrics import scale_free_relmse

METHODS = [("raymarch", {"steps": 256, "shadowmap_resolution": 512}),
           ("epipolar_tree", {}), ("fourier_filter", {})]


def scene(light):
    T = mi.ScalarTransform4f
    lights = {"directional": {"type": "directional", "direction": [0.3, -1.0, -0.4],
                              "irradiance": {"type": "rgb", "value": [1.0, 0.9, 0.7]}},
              "spot": {"type": "spot", "to_world": T().look_at(origin=[0.5, 2.5, 0.5],
                                                                target=[0, -1, 0], up=[0, 0, 1]),
                       "cutoff_angle": 40.0, "intensity": {"type": "rgb", "value": [8, 7, 5]}}}
    return mi.load_dict({
        "type": "scene",
        "medium": {"type": "homogeneous", "id": "medium", "albedo": 0.8,
                   "sigma_t": {"type": "rgb", "value": [0.2, 0.3, 0.4]},
                   "phase": {"type": "hg", "g": 0.3}},
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": T().look_at(origin=[0, 0.5, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": 24, "height": 18,
                            "rfilter": {"type": "box"}},
                   "medium": {"type": "ref", "id": "medium"}},
        "box": {"type": "cube", "to_world": T().scale(4.0), "bsdf": {"type": "null"},
                "interior": {"type": "ref", "id": "medium"}},
        "floor": {"type": "rectangle",
                  "to_world": T().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": 0.5}},
        "blocker": {"type": "sphere", "center": [0, 0.8, 0], "radius": 0.4,
                    "bsdf": {"type": "diffuse", "reflectance": 0.5}},
        "light": lights[light]})


def main(variants):
    for variant in variants:
        mi.set_variant(variant)
        for light in ("directional", "spot"):
            sc = scene(light)
            ref = np.array(mi.render(sc, integrator=mi.load_dict(
                {"type": "raymarch", "visibility": "exact", "steps": 1024})))
            for kind, props in METHODS:
                img = np.array(mi.render(sc, integrator=mi.load_dict({"type": kind, **props})))
                print("ROW", json.dumps({"variant": variant, "light": light, "method": kind,
                                  "channels": int(img.shape[-1]),
                                  "finite": bool(np.all(np.isfinite(img))),
                                  "mean": float(img.mean()), "ref_mean": float(ref.mean()),
                                  "relmse": float(scale_free_relmse(img, ref))}), flush=True)


if __name__ == "__main__":
    main(sys.argv[1:])

"""Shared test fixtures: a small scene factory built with mi.load_dict."""
import integrators  # noqa: F401  (sets the variant, registers plugins)
import mitsuba as mi
import csv

import pytest

T = mi.ScalarTransform4f

LIGHTS = {
    "directional": {"type": "directional", "direction": [0.3, -1, -0.2], "irradiance": 2.0},
    "spot": {"type": "spot", "intensity": 20, "cutoff_angle": 35, "beam_width": 25,
             "to_world": T().look_at(origin=[0.5, 2.5, 0.5], target=[0, -1, 0], up=[0, 0, 1])},
    "spot_textured": {"type": "spot", "intensity": 20, "cutoff_angle": 35, "beam_width": 25,
                      "to_world": T().look_at(origin=[0.5, 2.5, 0.5], target=[0, -1, 0], up=[0, 0, 1]),
                      "texture": {"type": "checkerboard",
                                  "color0": {"type": "rgb", "value": [1, 0.2, 0.1]},
                                  "color1": {"type": "rgb", "value": [0.1, 0.3, 1]},
                                  "to_uv": mi.ScalarTransform3f().scale(4)}},
    "point": {"type": "point", "position": [0.3, 2.0, 0.4], "intensity": 10},
}


def scene_dict(light="directional", phase=None, sigma_t=0.3, albedo=0.8, res=(32, 24),
               surface=0.5, box_scale=4.0, camera=None, **overrides):
    """A small test scene: camera inside a fog box, a floor, a blocker sphere."""
    camera = camera or {"origin": [0, 0.5, 3], "target": [0, 0, 0], "up": [0, 1, 0]}
    d = {
        "type": "scene",
        "integrator": {"type": "volpath", "max_depth": 2},
        "medium": {"type": "homogeneous", "id": "medium", "sigma_t": sigma_t, "albedo": albedo,
                   "phase": phase or {"type": "isotropic"}},
        "sensor": {"type": "perspective", "fov": 60,
                   "to_world": T().look_at(**camera),
                   "film": {"type": "hdrfilm", "width": res[0], "height": res[1],
                            "rfilter": {"type": "box"}},
                   "medium": {"type": "ref", "id": "medium"},
                   "sampler": {"type": "independent", "sample_count": 1}},
        "box": {"type": "cube", "to_world": T().scale(box_scale), "bsdf": {"type": "null"},
                "interior": {"type": "ref", "id": "medium"}},
        "floor": {"type": "rectangle",
                  "to_world": T().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": surface}},
        "blocker": {"type": "sphere", "center": [0, 0.8, 0], "radius": 0.4,
                    "bsdf": {"type": "diffuse", "reflectance": surface}},
        "light": LIGHTS[light] if isinstance(light, str) else light,
    }
    d.update(overrides)
    return {k: v for k, v in d.items() if v is not None}


@pytest.fixture
def make_scene():
    def make(**kw):
        return mi.load_dict(scene_dict(**kw))
    return make


@pytest.fixture
def cache(tmp_path, monkeypatch):
    """References made by a test go to a temporary cache."""
    folder = tmp_path / "cache"
    monkeypatch.setenv("EPISCATTER_CACHE", str(folder))
    return folder


def read_csv(path):
    with open(path, newline="") as f:
        return list(csv.DictReader(f))

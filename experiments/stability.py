"""Numerical stability of ``epipolar_tree`` and ``fourier_filter`` on stress
cases (issue point 5).

No paper table mirrors this (Baran 2010 §3 and §8 and Klehm 2014 §4 discuss
the epipole cases only in words); it checks the geometric corner cases of
the epipolar rectification and extreme media/scales for NaN/Inf and bounded
error.  Each case is a small test scene (64x48; camera inside a fog box, a
floor, a blocker sphere, see :func:`stress_scene`) rendered by both methods
at their defaults and by the exact working reference (``raymarch
visibility=exact``, 2048 steps, 1 spp at the pixel centres, the same
samples).  Cases:

- ``epipole``: the epipole (directional light) exactly on a pixel centre,
  on the left image border, on an image corner, at infinity (light
  parallel to the image plane) and 1e-4 rad off it, behind the camera (the
  anti-epipole on a pixel centre); a point light on a pixel centre, behind
  the camera and in the camera's image plane (epipole at infinity);
- ``sigma_t``: σt = 1e-4 ... 10 per unit (box half-size 4), and 30 and 100
  beyond the issue's range (light-side optical depths > 88, where
  e^{σt·u} overflows float32);
- ``scale``: the whole scene (positions, sizes, medium box, near/far clip)
  scaled by 0.01 ... 10,000, with σt scaled inversely (same optical depths:
  the image must not change; the reference's own deviation from scale 1 is
  listed) and with σt fixed; a point light (intensity · scale², so the
  image again must not change) in the first variant;
- ``grazing``: a light grazing the fog box's top face (directional at 6°,
  point lights at 5° far out and just above the face), the camera just
  under that face looking away from the light, σt = 0.3 ... 10: most light
  rays of a slice leave the box far behind the eye, the light-side factor
  spans e^{±σt·80} (before ``epipolar.light_rays.directional.row_reference`` bounded it,
  images were off by up to 1e9).

Per case and method: NaN/Inf pixel count, relMSE (eps 1e-2), max |error|,
max |error| / max(reference), mean ratio.  ``bounded`` = no NaN/Inf and
relMSE <= 1e-2 (BOUND) and max |error| <= 0.5 · max(reference) (PEAK_BOUND).  A method that rejects a case (e.g. a point light
not supported yet) is recorded with its status.

Writes ``results/stability/``: ``stability.csv``, ``stability.json``,
``table.md``, ``stability.png``.  ``python -m experiments.stability [--quick]``.
"""
from __future__ import annotations

import math
import re

import numpy as np

from episcatter.reference import exact_description, exact_props

from . import common as c

NAME = "stability"
METHODS = ("epipolar_tree", "fourier_filter")
#: relMSE at or below which a finite image counts as "bounded" ...
BOUND = 1e-2
#: ... if also no pixel is off by more than this fraction of the reference's peak
PEAK_BOUND = 0.5
CAMERA = {"origin": [0.0, 0.5, 3.0], "target": [0.0, 0.0, 0.0], "up": [0.0, 1.0, 0.0]}
FOV = 60.0
DEFAULT_DIRECTION = [0.3, -1.0, -0.2]
SIGMA_T = 0.3


# --------------------------------------------------------------------------
# Scenes
# --------------------------------------------------------------------------

def stress_scene(light: dict, sigma_t: float = SIGMA_T, scale: float = 1.0,
                 res=(64, 48), albedo: float = 0.8, camera: dict | None = None) -> dict:
    """Scene dict: camera in a fog box (half-size 4), a floor, a blocker
    sphere; every length (and the clip planes) multiplied by ``scale``.
    ``light`` is a directional or point emitter dict (point positions are
    given at scale 1 and scaled here); ``camera``: origin/target/up
    (default ``CAMERA``)."""
    import mitsuba as mi

    T = mi.ScalarTransform4f
    s = float(scale)
    camera = camera or CAMERA
    cam = {k: [s * v for v in camera[k]] if k != "up" else camera[k] for k in camera}
    light = dict(light)
    if light["type"] == "point":
        light["position"] = [s * v for v in light["position"]]
    return {
        "type": "scene",
        "medium": {"type": "homogeneous", "id": "medium", "sigma_t": float(sigma_t),
                   "albedo": albedo, "phase": {"type": "isotropic"}},
        "sensor": {"type": "perspective", "fov": FOV, "near_clip": 0.01 * s,
                   "far_clip": 1e4 * s, "to_world": T().look_at(**cam),
                   "film": {"type": "hdrfilm", "width": res[0], "height": res[1],
                            "rfilter": {"type": "box"}},
                   "medium": {"type": "ref", "id": "medium"}},
        "box": {"type": "cube", "to_world": T().scale(4.0 * s), "bsdf": {"type": "null"},
                "interior": {"type": "ref", "id": "medium"}},
        "floor": {"type": "rectangle",
                  "to_world": T().scale(s).translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse", "reflectance": 0.5}},
        "blocker": {"type": "sphere", "center": [0, 0.8 * s, 0], "radius": 0.4 * s,
                    "bsdf": {"type": "diffuse", "reflectance": 0.5}},
        "light": light,
    }


def pixel_direction(u: float, v: float, res=(64, 48)) -> list[float]:
    """World direction of the camera ray through film position (u, v) in
    [0, 1]² (pixel (i, j)'s centre: ((i + ½)/W, (j + ½)/H))."""
    import mitsuba as mi

    sensor = dict(stress_scene(directional(DEFAULT_DIRECTION), res=res)["sensor"])
    sensor.pop("medium")
    sensor = mi.load_dict(sensor)
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(u, v), mi.Point2f(0.5, 0.5))
    return [float(x[0]) for x in (ray.d.x, ray.d.y, ray.d.z)]


def camera_axes() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(right, up, forward) unit vectors of the camera."""
    o, t, up = (np.array(CAMERA[k], float) for k in ("origin", "target", "up"))
    f = (t - o) / np.linalg.norm(t - o)
    r = np.cross(up, f)
    r /= np.linalg.norm(r)
    return r, np.cross(f, r), f


def directional(direction) -> dict:
    return {"type": "directional", "direction": [float(x) for x in direction],
            "irradiance": 2.0}


def point(position, intensity: float = 10.0) -> dict:
    return {"type": "point", "position": [float(x) for x in position],
            "intensity": float(intensity)}


# --------------------------------------------------------------------------
# Cases
# --------------------------------------------------------------------------

def epipole_cases(res) -> list[dict]:
    """The epipole cases (module doc).  A directional light's ``direction``
    is the way its light travels, so −ray puts the epipole (the sun) on that
    pixel and +ray puts the sun behind the camera."""
    W, H = res
    i, j = W * 5 // 16, H * 7 // 24                 # pixel (20, 14) at 64x48
    centre = pixel_direction((i + 0.5) / W, (j + 0.5) / H, res)
    border = pixel_direction(0.0, (H * 5 // 8 + 0.5) / H, res)
    corner = pixel_direction(0.0, 0.0, res)
    right, up, fwd = camera_axes()
    eye = np.array(CAMERA["origin"], float)
    tilt = 1e-4
    parallel = -(0.8 * right + 0.6 * up)          # light parallel to the image plane
    near_parallel = parallel + math.tan(tilt) * fwd
    cases = [
        (f"epipole on pixel centre ({i},{j})", directional(-np.array(centre))),
        ("epipole on left border", directional(-np.array(border))),
        ("epipole on top-left corner", directional(-np.array(corner))),
        ("epipole at infinity (light parallel to image plane)", directional(parallel)),
        ("epipole near infinity (1e-4 rad)", directional(near_parallel)),
        ("epipole behind camera (anti-epipole on pixel centre)", directional(centre)),
        ("point: epipole on pixel centre", point(eye + 2.0 * np.array(centre))),
        ("point: behind camera", point(eye - 2.0 * np.array(centre))),
        ("point: in the image plane (epipole at infinity)",
         point(eye + 1.5 * right + 0.5 * up)),
    ]
    return [{"group": "epipole", "case": name, "light": light, "sigma_t": SIGMA_T, "scale": 1.0}
            for name, light in cases]


def sigma_cases(values) -> list[dict]:
    return [{"group": "sigma_t", "case": f"sigma_t = {v:g}", "light": directional(DEFAULT_DIRECTION),
             "sigma_t": v, "scale": 1.0} for v in values]


def scale_cases(values) -> list[dict]:
    """Scaled scenes: optical depth kept (σt / scale), σt fixed, and a point
    light with optical depth kept (intensity · scale²)."""
    out = []
    for s in values:
        out.append({"group": "scale, optical depth fixed", "case": f"scale {s:g}",
                    "light": directional(DEFAULT_DIRECTION), "sigma_t": SIGMA_T / s, "scale": s})
        out.append({"group": "scale, sigma_t fixed", "case": f"scale {s:g}",
                    "light": directional(DEFAULT_DIRECTION), "sigma_t": SIGMA_T, "scale": s})
        out.append({"group": "scale, point light, optical depth fixed", "case": f"scale {s:g}",
                    "light": point([0.3, 2.0, 0.4], 10.0 * s * s), "sigma_t": SIGMA_T / s,
                    "scale": s})
    return out


#: camera just under the box's top face (y = 4), looking away from a light
#: that grazes that face: most light rays of a slice leave the box far
#: behind the eye (epipolar.light_rays.directional.row_reference)
UNDER_TOP = {"origin": [0.0, 3.9, 0.0], "target": [3.0, 3.5, 0.0], "up": [0.0, 1.0, 0.0]}


def grazing_cases(values) -> list[dict]:
    """Light grazing the box's top face at 6°, camera under it looking away
    from the light (``UNDER_TOP``): directional, and a point light far out
    (5°) and one just above the face, for each σt in ``values``."""
    sun = directional([math.cos(math.radians(6.0)), -math.sin(math.radians(6.0)), 0.0])
    lights = [("directional 6°", sun), ("point far (5°)", point([-30.0, 6.5, 0.0], 9000.0)),
              ("point near the face", point([-5.0, 4.3, 0.0], 9000.0))]
    return [{"group": "grazing light, camera under the box top", "case": f"{name}, σt = {v:g}",
             "light": light, "sigma_t": v, "scale": 1.0, "camera": UNDER_TOP}
            for v in values for name, light in lights]


def settings_for(quick: bool) -> dict:
    if quick:
        return {"res": (32, 24), "reference_steps": 256, "sigma_t": [10.0],
                "scales": [1.0, 1e4], "epipole": True, "grazing_sigma_t": [10.0]}
    return {"res": (64, 48), "reference_steps": c.REFERENCE_STEPS,
            "sigma_t": [1e-4, 1e-3, 1e-2, 0.1, 1.0, 10.0, 30.0, 100.0],
            "scales": [0.01, 0.1, 1.0, 10.0, 100.0, 1e3, 1e4], "epipole": True,
            "grazing_sigma_t": [0.3, 1.0, 3.0, 10.0]}


def all_cases(s: dict) -> list[dict]:
    cases = epipole_cases(s["res"]) if s["epipole"] else []
    if s.get("quick_subset"):
        cases = cases[:2]
    return (cases + sigma_cases(s["sigma_t"]) + scale_cases(s["scales"])
            + grazing_cases(s.get("grazing_sigma_t", [])))


# --------------------------------------------------------------------------
# Measuring
# --------------------------------------------------------------------------

def render(scene, kind: str, props: dict):
    """(image, status): the rendered (H, W, 3) image or None and why not."""
    from episcatter.reference import render_rgb

    try:
        return render_rgb(scene, c.build(kind, props), spp=1), "ok"
    except Exception as exc:  # noqa: BLE001 -- recorded, the other cases go on
        return None, c.describe_error(exc)


def stats(img, ref) -> dict:
    """NaN/Inf count, relMSE, max |error| (absolute and / max ref), mean ratio."""
    e = c.errors(img, ref, blocks=(1,))
    finite = np.all(np.isfinite(img), axis=-1)
    diff = np.abs(np.where(finite[..., None], img, 0.0) - ref)
    peak = float(np.max(np.abs(ref)))
    max_abs = float(np.max(diff[finite])) if finite.any() else math.nan
    return {"nonfinite": e["nonfinite"], "relmse": e["relmse_b1"], "max_abs_error": max_abs,
            "max_rel_to_peak": max_abs / peak if peak > 0 else math.nan,
            "mean_ratio": e["mean_ratio_b1"], "ref_peak": peak,
            "bounded": bounded(e["nonfinite"], e["relmse_b1"], max_abs, peak,
                               e["mean_ratio_b1"])}


#: |mean ratio - 1| at or below which the energy counts as right
MEAN_RATIO_BOUND = 0.1


def bounded(nonfinite: int, relmse: float, max_abs: float, peak: float,
            mean_ratio: float = 1.0) -> bool:
    """No NaN/Inf, scale-free relMSE <= BOUND, max |error| <= PEAK_BOUND · peak
    (an all-black reference needs an all-black image) and the mean ratio
    (energy) within MEAN_RATIO_BOUND of 1 (NaN for a black reference: not
    checked)."""
    energy_ok = not (abs(mean_ratio - 1.0) > MEAN_RATIO_BOUND)
    return bool(nonfinite == 0 and relmse <= BOUND and max_abs <= PEAK_BOUND * peak
                and energy_ok)


def run_case(case: dict, s: dict, scale1_refs: dict) -> list[dict]:
    """The reference and both methods on one case (one row per method)."""
    import mitsuba as mi

    scene = mi.load_dict(stress_scene(case["light"], case["sigma_t"], case["scale"], s["res"],
                                      camera=case.get("camera")))
    ref, status = render(scene, "raymarch", exact_props(s["reference_steps"]))
    base = {"group": case["group"], "case": case["case"], "sigma_t": case["sigma_t"],
            "scale": case["scale"], "light": case["light"]["type"]}
    if ref is None:
        return [{**base, "method": "reference", "status": status}]
    key = case["group"]
    if case["scale"] == 1.0:
        scale1_refs[key] = ref
    ref_dev = (c.errors(ref, scale1_refs[key], blocks=(1,))["relmse_b1"]
               if key in scale1_refs and key.startswith("scale") and "fixed" in key
               and "sigma_t fixed" not in key else math.nan)
    rows = []
    for kind in METHODS:
        img, status = render(scene, kind, {})
        row = {**base, "method": kind, "status": status, "ref_nonfinite":
               int((~np.all(np.isfinite(ref), axis=-1)).sum()),
               "ref_relmse_vs_scale1": ref_dev}
        if img is not None:
            row.update(stats(img, ref))
        rows.append(row)
    return rows


def ordered(cases: list[dict]) -> list[dict]:
    """Scale 1 first in each scale group, so later scales can be compared
    with its reference."""
    return sorted(cases, key=lambda k: (k["group"] != "epipole", k["scale"] != 1.0))


# --------------------------------------------------------------------------
# Report
# --------------------------------------------------------------------------

def table(rows: list[dict]) -> str:
    header = ["group", "case", "method", "NaN/Inf px", "relMSE", "max abs err",
              "max err / peak", "mean ratio", "bounded", "status"]
    body = []
    for r in rows:
        ok = r["status"] == "ok"
        body.append([r["group"], r["case"], r["method"],
                     c.fmt(r.get("nonfinite")) if ok else "-", c.fmt(r.get("relmse")),
                     c.fmt(r.get("max_abs_error")), c.fmt(r.get("max_rel_to_peak")),
                     c.fmt(r.get("mean_ratio"), 4),
                     ("yes" if r.get("bounded") else "**no**") if ok else "-",
                     "ok" if ok else r["status"][:80]])
    return c.markdown_table(header, body)


def summary(rows: list[dict]) -> str:
    lines = []
    for kind in METHODS:
        mine = [r for r in rows if r["method"] == kind]
        ok = [r for r in mine if r["status"] == "ok"]
        bad = [f"{r['group']} / {r['case']}" for r in ok if not r["bounded"]]
        lines.append(f"- {kind}: {len(ok)}/{len(mine)} cases rendered, "
                     f"{sum(r['nonfinite'] for r in ok)} NaN/Inf pixels in total, "
                     f"{len(ok) - len(bad)} bounded; unbounded: "
                     + ("; ".join(bad) if bad else "none")
                     + f"; not rendered: {len(mine) - len(ok)}")
    return "\n".join(lines)


def plot(path, rows) -> None:
    """Per case and method: relMSE and max |error| / peak (log scale; a
    black image against a black reference sits at the left edge); red x =
    NaN/Inf pixels."""
    plt = c.pyplot()
    label = (lambda r: f"{r['group'][:14]}: {r['case'][:34]}")
    labels = list(dict.fromkeys(label(r) for r in rows if r["method"] in METHODS))
    fig, axes = plt.subplots(1, 2, figsize=(9, 0.17 * len(labels) + 1.3), sharey=True)
    floor = 1e-12
    for ax, key, bound in ((axes[0], "relmse", BOUND), (axes[1], "max_rel_to_peak", PEAK_BOUND)):
        for kind, marker in zip(METHODS, "os"):
            pts, bad = [], []
            for i, lab in enumerate(labels):
                r = next((r for r in rows if r["method"] == kind and label(r) == lab), None)
                if r and r["status"] == "ok":
                    v = r.get(key)
                    pts.append((max(v, floor) if v == v and v is not None else floor, i))
                    if r["nonfinite"]:
                        bad.append(pts[-1])
            if pts:
                ax.plot(*zip(*pts), marker, ms=4, label=kind, alpha=0.8)
            if bad:
                ax.plot(*zip(*bad), "x", color="red", ms=8)
        ax.axvline(bound, color="gray", ls="--", lw=0.8)
        ax.set_xscale("log")
        ax.set_xlabel({"relmse": "relMSE vs exact raymarch",
                       "max_rel_to_peak": "max |error| / max(reference)"}[key], fontsize=8)
        ax.grid(True, axis="x", alpha=0.3)
    axes[0].set_yticks(range(len(labels)), labels, fontsize=6)
    axes[0].invert_yaxis()
    axes[0].legend(fontsize=7, title="red x: NaN/Inf; missing: not rendered",
                   title_fontsize=6)
    c.savefig(fig, path)


def case_order(rows: list[dict], cases: list[dict]) -> list[dict]:
    """Rows in the order of ``cases`` (ascending scale within a group)."""
    pos = {(k["group"], k["case"]): i for i, k in enumerate(cases)}
    return sorted(rows, key=lambda r: pos.get((r["group"], r["case"]), len(pos)))



# --------------------------------------------------------------------------
# Randomised stress set (issue 13): experiments.random_scenes
# --------------------------------------------------------------------------

#: integrators of the randomised set, each at its defaults
RANDOM_METHODS = ("raymarch", "epipolar_tree", "fourier_filter")
#: mean ratio must lie within this of 1 on lit references ...
MEAN_BOUND = 0.02
#: ... and a black reference may receive at most this fraction of the unoccluded peak
LEAK_BOUND = 1e-3
#: references whose peak is below this (but not 0) are invisible at any exposure: not judged
INVISIBLE_PEAK = 1e-12


def reference_class(peak: float) -> str:
    """``black`` (peak 0: judged by the leak), ``invisible`` (0 < peak <
    ``INVISIBLE_PEAK``: not judged) or ``lit``."""
    if peak == 0.0:
        return "black"
    return "invisible" if peak < INVISIBLE_PEAK else "lit"


def random_stats(img, ref, unoccluded_peak: float) -> dict:
    """Per image against the reference at pixel centres (scattering only):
    NaN/Inf count, scale-free relMSE, mean ratio, max |error| / reference
    peak, leak (largest value / unoccluded peak) and whether the issue-13
    bounds hold for the reference's class (:func:`reference_class`)."""
    from episcatter import metrics

    finite = np.all(np.isfinite(img), axis=-1)
    nonfinite = int((~finite).sum())
    img = np.where(finite[..., None], img, 0.0)
    peak = float(np.max(ref))
    cls = reference_class(peak)
    out = {"nonfinite": nonfinite, "ref_class": cls, "ref_peak": peak,
           "unoccluded_peak": unoccluded_peak, "relmse": math.nan, "mean_ratio": math.nan,
           "max_rel_to_peak": math.nan, "leak": math.nan}
    if cls == "black":
        leak = float(np.max(np.abs(img))) / unoccluded_peak if unoccluded_peak > 0 else 0.0
        out.update(leak=leak, bounded=bool(nonfinite == 0 and leak <= LEAK_BOUND))
        return out
    out.update(relmse=metrics.scale_free_relmse(img, ref), mean_ratio=metrics.mean_ratio(img, ref),
               max_rel_to_peak=float(np.max(np.abs(img - ref))) / peak)
    out["bounded"] = bool(cls == "invisible" or (
        nonfinite == 0 and out["relmse"] <= BOUND and out["max_rel_to_peak"] <= PEAK_BOUND
        and abs(out["mean_ratio"] - 1.0) <= MEAN_BOUND))
    return out


def run_random_scene(spec, methods=RANDOM_METHODS, reference_steps: int = c.REFERENCE_STEPS,
                     params: dict | None = None) -> list[dict]:
    """The exact reference and each of ``methods`` (at its defaults, plus
    ``params[method]`` if given) on one generated scene, scattering only, one
    row per method; the unoccluded reference's peak only where the reference
    is black."""
    scene = spec.load()
    exact = {**exact_props(reference_steps), "output": "scattering"}
    ref, status = render(scene, "raymarch", exact)
    base = {"seed": spec.seed, "kind": spec.kind, "light": spec.light["type"],
            "lights": len(spec.lights), "boundary": spec.boundary,
            "camera_outside": spec.camera_outside, "features": "+".join(spec.features) or "-",
            "res": f"{spec.res[0]}x{spec.res[1]}", "sigma_t_B": spec.sigma_t * spec.box_half,
            "occluders": len(spec.occluders)}
    if ref is None:
        return [{**base, "method": "reference", "status": status}]
    unoccluded = math.nan
    if reference_class(float(np.max(ref))) == "black":
        free, _ = render(spec.load(occluders=False), "raymarch", exact)
        unoccluded = float(np.max(free)) if free is not None else math.nan
    rows = []
    for kind in methods:
        img, status = render(scene, kind, {"output": "scattering",
                                           **(params or {}).get(kind, {})})
        row = {**base, "method": kind, "status": status}
        if img is not None:
            row.update(random_stats(img, ref, unoccluded))
        else:
            row["bounded"] = False
        rows.append(row)
    return rows


def distribution(values) -> dict:
    """median, 90th percentile and max of the finite ``values`` (NaN if none)."""
    v = np.asarray([x for x in values if x is not None and x == x], float)
    if not v.size:
        return {"median": math.nan, "p90": math.nan, "max": math.nan, "n": 0}
    return {"median": float(np.median(v)), "p90": float(np.percentile(v, 90)),
            "max": float(np.max(v)), "n": int(v.size)}


def random_summary(rows: list[dict], methods=RANDOM_METHODS) -> dict:
    """Per method: scenes, bounded count, failures by kind, and the
    distributions of relMSE, max error / peak, |mean ratio - 1| (lit
    references) and leak (black references)."""
    out = {}
    for kind in methods:
        mine = [r for r in rows if r["method"] == kind]
        lit = [r for r in mine if r.get("ref_class") == "lit"]
        black = [r for r in mine if r.get("ref_class") == "black"]
        failed = [r for r in mine if not r.get("bounded")]
        out[kind] = {
            "scenes": len(mine), "lit": len(lit), "black": len(black),
            "invisible": sum(r.get("ref_class") == "invisible" for r in mine),
            "not_rendered": sum(r["status"] != "ok" for r in mine),
            "nonfinite_scenes": sum(bool(r.get("nonfinite")) for r in mine),
            "bounded": len(mine) - len(failed),
            "unbounded_seeds": [r["seed"] for r in failed],
            "unbounded_by_kind": {k: sum(r["kind"] == k for r in failed)
                                  for k in sorted({r["kind"] for r in failed})},
            "relmse": distribution(r["relmse"] for r in lit),
            "max_rel_to_peak": distribution(r["max_rel_to_peak"] for r in lit),
            "mean_ratio_dev": distribution(abs(r["mean_ratio"] - 1.0) for r in lit),
            "leak": distribution(r["leak"] for r in black),
            "by_lights": {n: {"scenes": sum(r.get("lights", 1) == n for r in mine),
                              "bounded": sum(r.get("lights", 1) == n and bool(r.get("bounded"))
                                             for r in mine),
                              "relmse": distribution(r["relmse"] for r in lit
                                                     if r.get("lights", 1) == n)}
                          for n in sorted({r.get("lights", 1) for r in mine})},
            "by_feature": {f: {"scenes": len(rs), "bounded": sum(bool(r.get("bounded")) for r in rs),
                               "relmse": distribution(r["relmse"] for r in rs
                                                      if r.get("ref_class") == "lit")}
                           for f in FEATURES
                           for rs in [[r for r in mine if _has_feature(r, f)]] if rs},
        }
    return out


#: the extended generator's features (experiments.random_scenes.SceneSpec.features)
FEATURES = ("none", "lights", "rotated_box", "sphere", "camera_outside")


def _has_feature(row: dict, feature: str) -> bool:
    have = [f for f in row.get("features", "-").split("+") if f != "-"]
    return not have if feature == "none" else feature in have


def random_text(summary: dict, n: int, first_seed: int, steps: int) -> str:
    header = ["method", "scenes (lit/black/invisible)", "bounded", "relMSE median / p90 / max",
              "max err/peak median / p90 / max", "|mean ratio-1| p90 / max", "leak max",
              "unbounded by kind"]
    body = []
    for kind, s in summary.items():
        d = s["relmse"], s["max_rel_to_peak"], s["mean_ratio_dev"]
        body.append([kind, f"{s['scenes']} ({s['lit']}/{s['black']}/{s['invisible']})",
                     f"{s['bounded']}/{s['scenes']}",
                     " / ".join(c.fmt(d[0][k]) for k in ("median", "p90", "max")),
                     " / ".join(c.fmt(d[1][k]) for k in ("median", "p90", "max")),
                     " / ".join(c.fmt(d[2][k]) for k in ("p90", "max")),
                     c.fmt(s["leak"]["max"]),
                     ", ".join(f"{k} {v}" for k, v in s["unbounded_by_kind"].items()) or "-"])
    parts = []
    if any(len(s["by_feature"]) > 1 for s in summary.values()):
        feats = [f for f in FEATURES if any(f in s["by_feature"] for s in summary.values())]
        parts += ["Per feature of the extended generator (a scene may have several): bounded / "
                  "scenes (relMSE median / max, lit references).",
                  c.markdown_table(["method"] + feats,
                                   [[kind] + [_by_lights_cell(s["by_feature"].get(f)) for f in feats]
                                    for kind, s in summary.items()])]
    if any(len(s["by_lights"]) > 1 for s in summary.values()):
        counts = sorted({k for s in summary.values() for k in s["by_lights"]})
        parts += ["Per number of lights: bounded / scenes (relMSE median / max, lit references).",
                 c.markdown_table(["method"] + [f"{k} light{'s' if k > 1 else ''}" for k in counts],
                                  [[kind] + [_by_lights_cell(s["by_lights"].get(k)) for k in counts]
                                   for kind, s in summary.items()])]
    return "\n\n".join([
        f"# stability, randomised set (seeds {first_seed}..{first_seed + n - 1})",
        "Scenes of experiments.random_scenes; each integrator at its defaults, output "
        f"scattering, 1 spp at pixel centres against {exact_description(steps)}. "
        f"Scale-free relMSE (eps 1e-2 x mean(ref)^2). Bounded: lit reference -> no NaN/Inf, "
        f"relMSE <= {BOUND:g}, max |error| <= {PEAK_BOUND:g} x peak, |mean ratio - 1| <= "
        f"{MEAN_BOUND:g}; black reference -> largest value <= {LEAK_BOUND:g} x the unoccluded "
        f"reference's peak; references with 0 < peak < {INVISIBLE_PEAK:g} are not judged.",
        c.markdown_table(header, body)] + parts)


def _by_lights_cell(cell) -> str:
    if not cell or not cell["scenes"]:
        return "-"
    d = cell["relmse"]
    return (f"{cell['bounded']}/{cell['scenes']} ({c.fmt(d['median'])} / {c.fmt(d['max'])})")


def run_random(n: int, first_seed: int, out, methods=RANDOM_METHODS,
               steps: int = c.REFERENCE_STEPS, tag: str = "random",
               params: dict | None = None, extended: bool = False) -> list[dict]:
    """The randomised set: ``n`` scenes from ``first_seed`` (``extended``:
    the extended generator's scenes), each method at its defaults plus
    ``params[method]``; writes ``<tag>.csv``, ``<tag>.json`` (settings,
    rows, summary) and ``<tag>.md``."""
    from . import random_scenes

    rows = []
    specs = random_scenes.scene_set(n, first_seed, extended=extended)
    for i, spec in enumerate(specs):
        new = run_random_scene(spec, methods, steps, params)
        rows += new
        print(f"[{i + 1}/{n}] {spec.name}: " + "; ".join(
            f"{r['method']} {'ok' if r.get('bounded') else 'UNBOUNDED'} "
            f"relMSE {c.fmt(r.get('relmse'))} max/peak {c.fmt(r.get('max_rel_to_peak'))} "
            f"mean {c.fmt(r.get('mean_ratio'), 4)} leak {c.fmt(r.get('leak'))}"
            for r in new), flush=True)
    summary = random_summary(rows, methods)
    settings = {"name": NAME, "set": tag, "scenes": n, "first_seed": first_seed,
                "extended": extended,
                "methods": list(methods), "params": params or {},
                "reference_steps": steps, "bound_relmse": BOUND,
                "bound_peak": PEAK_BOUND, "bound_mean": MEAN_BOUND, "bound_leak": LEAK_BOUND,
                "invisible_peak": INVISIBLE_PEAK, "output": "scattering",
                "specs": [s.as_json() for s in specs]}
    c.write_csv(out / f"{tag}.csv", rows)
    c.write_json(out / f"{tag}.json", settings, rows, summary=summary)
    text = random_text(summary, n, first_seed, steps)
    c.write_text(out / f"{tag}.md", text)
    print(text)
    return rows



LOG_LINE = re.compile(r"^\[\d+/\d+\] seed (\d+) \((\w+), (\w+)(?: \+\d+ lights)?(?: \w+)?"
                      r"(?: outside)?, (\d+x\d+)\): (.*)$")
LOG_METHOD = re.compile(r"(\w+) (ok|UNBOUNDED) relMSE (\S+) max/peak (\S+) mean (\S+) leak (\S+)")


def parse_log(path) -> list[dict]:
    """Rows of a ``--random`` run's progress log (one line per scene; the
    CSV is written only at the end, so an interrupted run keeps its log):
    seed, kind, light, res, method, bounded, relmse, max_rel_to_peak,
    mean_ratio, leak (3 significant digits; NaN where the log has "-"),
    ref_class ``black`` where a leak is given, ``failed`` where nothing is."""
    def num(x):
        return math.nan if x == "-" else float(x)

    rows = []
    for line in open(path):
        m = LOG_LINE.match(line.strip())
        if not m:
            continue
        seed, kind, light, res, rest = m.groups()
        for part in rest.split("; "):
            k = LOG_METHOD.match(part)
            if not k:
                continue
            method, ok, relmse, peak, mean, leak = k.groups()
            values = [num(v) for v in (relmse, peak, mean, leak)]
            cls = ("black" if values[3] == values[3] else
                   "failed" if all(v != v for v in values) else "lit")
            if cls == "lit" and ok == "ok" and not (
                    values[0] <= BOUND and values[1] <= PEAK_BOUND
                    and abs(values[2] - 1.0) <= MEAN_BOUND):
                cls = "invisible"        # judged ok only because its peak is < INVISIBLE_PEAK
            rows.append({"seed": int(seed), "kind": kind, "light": light, "res": res,
                         "method": method, "bounded": ok == "ok", "relmse": values[0],
                         "max_rel_to_peak": values[1], "mean_ratio": values[2],
                         "leak": values[3], "ref_class": cls,
                         "status": "failed" if cls == "failed" else "ok"})
    return rows


def compare_logs(before: list, after: list, out, method: str = "epipolar_tree") -> dict:
    """Before/after summaries (:func:`random_summary`) of ``method`` on the
    seeds both sets of logs cover; writes ``random_before.csv``,
    ``random_after.csv``, ``random_compare.json`` and ``random_compare.md``."""
    def rows_of(paths):
        rows = {}
        for path in paths:
            for r in parse_log(path):
                if r["method"] == method:
                    rows.setdefault(r["seed"], r)
        return rows
    b, a = rows_of(before), rows_of(after)
    seeds = sorted(set(b) & set(a))
    rb, ra = [b[k] for k in seeds], [a[k] for k in seeds]
    summary = {"seeds": seeds, "before": random_summary(rb, (method,))[method],
               "after": random_summary(ra, (method,))[method]}
    c.write_csv(out / "random_before.csv", rb)
    c.write_csv(out / "random_after.csv", ra)
    c.write_json(out / "random_compare.json", {"name": NAME, "method": method,
                                               "before_logs": [str(p) for p in before],
                                               "after_logs": [str(p) for p in after]},
                 [], summary=summary)
    text = random_text({f"{method} before": summary["before"],
                        f"{method} after": summary["after"]},
                       len(seeds), seeds[0] if seeds else 0, c.REFERENCE_STEPS)
    text += f"\n\nSeeds compared ({len(seeds)}): {seeds}\n"
    c.write_text(out / "random_compare.md", text)
    print(text)
    return summary


def summarise_logs(paths, out, tag: str, method: str = "epipolar_tree") -> dict:
    """The :func:`random_summary` of ``method`` over the progress logs
    ``paths`` of one set of ``--random`` runs (e.g. a long run split into
    several processes); writes ``<tag>.csv`` and ``<tag>.md``."""
    rows = {}
    for path in paths:
        for r in parse_log(path):
            if r["method"] == method:
                rows.setdefault(r["seed"], r)
    seeds = sorted(rows)
    rows = [rows[k] for k in seeds]
    summary = random_summary(rows, (method,))
    c.write_csv(out / f"{tag}.csv", rows)
    text = random_text(summary, len(seeds), seeds[0] if seeds else 0, c.REFERENCE_STEPS)
    text += f"\n\nLogs: {', '.join(str(p) for p in paths)}; seeds {len(seeds)}\n"
    c.write_text(out / f"{tag}.md", text)
    print(text)
    return summary


def method_settings(items, methods) -> dict:
    """``{method: {key: value}}`` of ``--set METHOD:KEY=VALUE`` items (values
    as Mitsuba reads strings); a method not in ``methods`` or an item
    without ``:`` and ``=`` is an error that names the form."""
    out = {}
    for item in items:
        method, _, kv = item.partition(":")
        key, eq, value = kv.partition("=")
        if not (method and key and eq):
            raise SystemExit(f"--set {item!r}: give METHOD:KEY=VALUE, e.g. "
                             "minmax_epipolar:small_image_march=false")
        if method not in methods:
            raise SystemExit(f"--set {item!r}: {method!r} is not one of --methods {methods}")
        out.setdefault(method, {})[key] = value
    return out


def main(argv=None):
    p = c.base_parser(__doc__, [], [])
    p.add_argument("--random", type=int, default=0, metavar="N",
                   help="run the randomised set of N generated scenes instead of the fixed cases")
    p.add_argument("--first-seed", type=int, default=0, help="first seed of --random")
    p.add_argument("--tag", default="random", help="file stem of --random's outputs")
    p.add_argument("--extended", action="store_true",
                   help="--random draws the extended generator's scenes (1-6 lights of mixed "
                        "kinds, box / rotated box / sphere boundaries, the camera inside or "
                        "outside)")
    p.add_argument("--methods", nargs="+", default=list(RANDOM_METHODS),
                   help="integrators of --random (default: all three)")
    p.add_argument("--set", action="append", default=[], metavar="METHOD:KEY=VALUE",
                   help="a property of one method of --random (repeatable), e.g. "
                        "minmax_epipolar:small_image_march=false")
    p.add_argument("--compare-logs", nargs=2, metavar=("BEFORE", "AFTER"), default=None,
                   help="comma-separated progress logs of two --random runs: before/after table")
    p.add_argument("--summarise-logs", default=None, metavar="LOGS",
                   help="comma-separated progress logs of one --random set: its summary "
                        "(written as <tag>.csv/.md)")
    args = p.parse_args(argv)
    if args.summarise_logs:
        return summarise_logs(args.summarise_logs.split(","),
                              c.output_dir(NAME, args.out, args.quick), args.tag)
    if args.compare_logs:
        return compare_logs(*(x.split(",") for x in args.compare_logs),
                            c.output_dir(NAME, args.out, args.quick))
    if args.random:
        out = c.output_dir(NAME, args.out, args.quick)
        return run_random(args.random, args.first_seed, out, tuple(args.methods),
                          steps=256 if args.quick else c.REFERENCE_STEPS, tag=args.tag,
                          params=method_settings(args.set, args.methods),
                          extended=args.extended)
    s = settings_for(args.quick)
    if args.quick:
        s["quick_subset"] = True
    out = c.output_dir(NAME, args.out, args.quick)
    rows, refs = [], {}
    for case in ordered(all_cases(s)):
        rows += run_case(case, s, refs)
    rows = case_order(rows, all_cases(s))
    text = "\n\n".join([
        f"# stability ({s['res'][0]}x{s['res'][1]}, 1 spp)",
        f"Against {exact_description(s['reference_steps'])} at the same pixel "
        f"centres; relMSE eps 1e-2; bounded = no NaN/Inf, relMSE <= {BOUND:g} and max |error| "
        f"<= {PEAK_BOUND:g} x the reference's peak (NaN/Inf pixels are left out of the other "
        "metrics). "
        "'ref_relmse_vs_scale1' in the CSV: the reference's own deviation from its scale-1 "
        "image where the scaled scene should look the same.",
        summary(rows), table(rows)])
    print(text)
    settings = {"name": NAME, **{k: v for k, v in s.items() if k != "quick_subset"},
                "quick": args.quick, "methods": list(METHODS), "bound_relmse": BOUND,
                "camera": CAMERA, "fov": FOV, "cases": [
                    {k: v for k, v in case.items()} for case in all_cases(s)]}
    c.write_csv(out / "stability.csv", rows)
    c.write_json(out / "stability.json", settings, rows)
    c.write_text(out / "table.md", text)
    plot(out / "stability.png", rows)
    return rows


if __name__ == "__main__":
    main()

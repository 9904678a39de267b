"""A new frame reuses the compiled kernels: moving the camera, moving the
light or changing σt between two renders compiles no new Dr.Jit kernel
(design: speed, new frames).

Counting is exact: ``dr.kernel_history()`` says for every launched JIT kernel
whether it was found in Dr.Jit's kernel cache.  Frame values (camera, light,
σt, counts read back from the device) must reach the kernels as opaque
parameters or data, never as literals in their source.  The moves are drawn
anew on every run: Dr.Jit's disk cache keeps the kernels of every frame it
has seen, so a fixed move would hit the cache on a second run and hide a
literal.
"""
from __future__ import annotations

import random

import drjit as dr
import mitsuba as mi
import numpy as np
import pytest

from episcatter.kernels import kernel_log, literal_changes


T = mi.ScalarTransform4f
W, H = 24, 18
INTEGRATORS = ("raymarch", "epipolar_tree", "fourier_filter", "minmax_epipolar")
LIGHTS = ("directional", "point", "spot", "textured_spot")
CHANGES = ("camera", "light", "sigma_t")

#: (integrator, light, change) that still compile kernels in the new frame,
#: and why; strict xfail, so a fix shows up as a failure to remove the entry
KNOWN = {}


def _light(kind, x):
    if kind == "directional":
        return {"type": "directional", "irradiance": 2.0,
                "to_world": T().look_at(origin=[0, 0, 0], target=[0.3 + 0.1 * x, -1, 0.2],
                                        up=[0, 0, 1])}
    if kind == "point":
        return {"type": "point", "intensity": 20.0, "position": [x, 2.5, 0.5]}
    light = {"type": "spot", "intensity": 20.0, "cutoff_angle": 35.0,
             "to_world": T().look_at(origin=[x, 2.5, 0.5], target=[0, -1, 0], up=[0, 0, 1])}
    if kind == "textured_spot":
        light["texture"] = {"type": "checkerboard", "to_uv": T().scale([4, 4, 1])}
    return light


def _scene(light_kind, cam_x, sigma_t, light_x):
    return mi.load_dict({
        "type": "scene",
        "medium": {"type": "homogeneous", "id": "fog", "sigma_t": sigma_t, "albedo": 0.8,
                   "phase": {"type": "hg", "g": 0.3}},
        "sensor": {"type": "perspective", "fov": 60, "medium": {"type": "ref", "id": "fog"},
                   "to_world": T().look_at(origin=[cam_x, 0.5, 3], target=[0, 0, 0], up=[0, 1, 0]),
                   "film": {"type": "hdrfilm", "width": W, "height": H, "rfilter": {"type": "box"}},
                   "sampler": {"type": "independent", "sample_count": 1}},
        "box": {"type": "cube", "to_world": T().scale(4.0), "bsdf": {"type": "null"},
                "interior": {"type": "ref", "id": "fog"}},
        "floor": {"type": "rectangle",
                  "to_world": T().translate([0, -1, 0]).rotate([1, 0, 0], -90).scale(3),
                  "bsdf": {"type": "diffuse"}},
        "blocker": {"type": "sphere", "center": [0, 0.8, 0], "radius": 0.4,
                    "bsdf": {"type": "diffuse"}},
        "light": _light(light_kind, light_x)})


def _frame(scene, integrator):
    with kernel_log() as log:
        dr.eval(mi.render(scene, integrator=integrator, spp=1))
    return log


def _move(scene, light_kind, change, cam, sigma_t, light_x):
    """Change the scene in place, as an animation does (``mi.traverse``)."""
    params = mi.traverse(scene)
    if change == "camera":
        params["sensor.to_world"] = T().look_at(origin=[cam, 0.5, 3], target=[0, 0, 0],
                                                up=[0, 1, 0])
    elif change == "light":
        light = _light(light_kind, light_x)
        key = "position" if light_kind == "point" else "to_world"
        params[f"light.{key}"] = light[key]
    else:
        key = next(k for k in params.keys() if k.endswith("sigma_t.value.value"))
        params[key] = sigma_t
    params.update()


@pytest.mark.parametrize("change", CHANGES)
@pytest.mark.parametrize("light", LIGHTS)
@pytest.mark.parametrize("kind", INTEGRATORS)
def test_a_new_frame_compiles_no_kernel(kind, light, change, request):
    reason = KNOWN.get((kind, light, change))
    if reason:
        request.applymarker(pytest.mark.xfail(reason=reason, strict=True))
    # one fixed move per case: a σt move that changes the automatic SVD
    # rank compiles the kernels unrolled over it once per new rank (a
    # different kernel, not a changed literal; docs/limitations.md)
    rng = random.Random(f"{kind}-{light}-{change}")
    cam, sigma, lx = rng.uniform(-0.2, 0.2), rng.uniform(0.2, 0.4), rng.uniform(0.3, 0.6)
    # minmax_epipolar's epipolar pipeline: at this image size its defaults
    # would march every pixel instead (small_image_march)
    extra = {"small_image_march": False} if kind == "minmax_epipolar" else {}
    integrator = mi.load_dict({"type": kind, **extra})
    scene = _scene(light, cam, sigma, lx)
    first = _frame(scene, integrator)
    step = rng.uniform(0.01, 0.05)
    _move(scene, light, change, cam + step, sigma * (1 + step), lx + step)
    second = _frame(scene, integrator)
    assert second.launched > 0
    assert second.compiled == 0, (
        f"{kind} compiled {second.compiled} of {second.launched} kernels after the {change} "
        f"moved; literals that changed: {literal_changes(first, second)[:4]}")


def test_the_same_frame_again_compiles_nothing():
    """The warm frame: nothing compiles, and the kernel log counts launches."""
    scene = _scene("point", 0.0, 0.3, 0.5)
    integrator = mi.load_dict({"type": "raymarch"})
    _frame(scene, integrator)
    again = _frame(scene, integrator)
    assert again.compiled == 0 and again.launched > 0
    assert again.compile_seconds == 0.0


def test_literal_changes_names_the_literal_that_moved():
    """The diagnosis of a recompile: a Python float in a kernel is found as
    the literal that differs between the two frames' kernels."""
    rng = random.Random()
    v1, v2 = (float(np.float32(rng.uniform(2.0, 3.0))) for _ in range(2))
    x = dr.arange(mi.Float, 64)
    with kernel_log() as a:
        dr.eval(x * v1 + 0.5)
    with kernel_log() as b:
        dr.eval(x * v2 + 0.5)
    changes = literal_changes(a, b)
    assert b.compiled == 1 and len(changes) == 1
    _, diff = changes[0]
    assert diff == [(v1, v2)]


def test_a_failed_render_leaves_nothing_for_the_next_frame(monkeypatch):
    """A render that fails after scheduling work (a stage that raises) does
    not leave it to be joined to the next render's kernels: the frame
    after it runs the kernels of every other frame (a kernel joined with
    the leftover would be one the frame after compiles again)."""
    import integrators.raymarch as rm
    scene = _scene("directional", 0.0, 0.3, 0.4)
    integrator = mi.load_dict({"type": "raymarch"})
    size = scene.sensors()[0].film().crop_size()
    lanes = int(size[0]) * int(size[1])
    _frame(scene, integrator)
    _frame(scene, integrator)

    held = []           # what the failed render still references (a traceback's locals)

    def failing(*args, **kw):
        # work of the frame's own width: the next frame's kernels of that width would take it
        held.append(dr.arange(mi.Float, lanes) * 3.0)
        dr.schedule(held[-1])
        raise RuntimeError("a stage failed")
    with monkeypatch.context() as m:
        m.setattr(rm.RaymarchIntegrator, "scattering", failing)
        with pytest.raises(RuntimeError, match="a stage failed"):
            integrator.render_layers(scene, spp=1)
    after = _frame(scene, integrator)
    again = _frame(scene, integrator)
    assert [k.get("hash") for k in after.entries] == [k.get("hash") for k in again.entries]

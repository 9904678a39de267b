"""Our pinhole model reproduces Mitsuba's perspective sensor exactly."""
import mitsuba as mi
import numpy as np
import pytest

from rectify.camera import CameraParams

T = mi.ScalarTransform4f


@pytest.mark.parametrize("fov,axis,res", [(50, "x", (64, 48)), (30, "y", (40, 60)),
                                          (90, "diagonal", (33, 17))])
def test_camera_matches_mitsuba_rays(fov, axis, res):
    sensor = mi.load_dict({
        "type": "perspective", "fov": fov, "fov_axis": axis, "near_clip": 0.3,
        "to_world": T().look_at(origin=[1, 2, 3], target=[0, -0.5, 0.2], up=[0.1, 1, 0]),
        "film": {"type": "hdrfilm", "width": res[0], "height": res[1]}})
    cam = CameraParams.from_mitsuba(sensor)
    rng = np.random.default_rng(1)
    uv = rng.random((50, 2))
    ray, _ = sensor.sample_ray(0.0, 0.5, mi.Point2f(uv[:, 0], uv[:, 1]), mi.Point2f(0.5, 0.5))
    d_mi = np.array(ray.d).T
    d_ours = cam.direction(uv[:, 0] * res[0], uv[:, 1] * res[1])
    d_ours /= np.linalg.norm(d_ours, axis=1, keepdims=True)
    np.testing.assert_allclose(d_ours, d_mi, atol=2e-6)
    # projection inverts the ray map
    p = cam.origin + 3.7 * d_ours
    x, y, z = cam.project(p)
    np.testing.assert_allclose(x, uv[:, 0] * res[0], atol=1e-4)
    np.testing.assert_allclose(y, uv[:, 1] * res[1], atol=1e-4)
    assert np.all(z > 0)
    # ray origins lie on the near plane through the pinhole
    o = np.array(ray.o).T
    np.testing.assert_allclose((o - cam.origin) @ cam.forward, 0.3, rtol=1e-4)

"""Animated scenes for temporal reuse (Lin et al.), generated on demand
(not part of the committed suite): ``python -m scenes.temporal [DIR]``.

* :func:`table1_scene` — the paper's Table 1 set-up: one point light in a
  box room, one moving object of about ``triangles`` triangles (a bumpy
  sphere mesh, :func:`blob_mesh`), turning in front of the camera; the
  motion spec is :data:`TABLE1_MOTION`.
* :func:`nave_swing` — the suite's ``nave_offscreen`` with a box swinging
  like a pendulum through the sun shafts (:data:`NAVE_SWING_MOTION`).

Files go to ``DIR`` (default ``scenes/meshes/temporal``, git-ignored); the
meshes are deterministic.
"""
from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

from . import catalog
from .assets import SCENE_DIR
from .meshes import ply_bytes, write_atomic
from .xmlbuild import Medium, Phase, SceneXML

DEFAULT_DIR = SCENE_DIR / "meshes" / "temporal"
#: the paper's model sizes (dragon ... yeahRight), in triangles
TABLE1_TRIANGLES = (50_000, 100_000, 250_000, 750_000)
#: the moving object of the Table 1 scenes: a quarter turn about the vertical
TABLE1_MOTION = "object:rotate=0,1,0,90"
#: the nave's pendulum: ±25° about the z axis through its hook
NAVE_SWING = dict(size=0.8, centre=(2.0, 8.0, -2.0), pivot=(2.0, 12.0, -2.0))
NAVE_SWING_MOTION = ("swinger:swing=0,0,1,25," + ",".join(str(c) for c in NAVE_SWING["pivot"]))


def blob_mesh(triangles: int, radius: float = 1.0, seed: int = 0):
    """A closed latitude–longitude sphere with ≈ ``triangles`` triangles,
    its radius modulated by a few random spherical waves (a bumpy,
    model-like silhouette).  Returns (vertices (n, 3), faces (m, 3))."""
    n_lat = max(4, int(round((1 + np.sqrt(1 + triangles)) / 2)))   # 4·n_lat·(n_lat − 1) triangles
    n_lon = 2 * n_lat
    rng = np.random.default_rng(seed)
    theta = np.linspace(0, np.pi, n_lat + 1)[1:-1]
    phi = np.linspace(0, 2 * np.pi, n_lon, endpoint=False)
    th, ph = np.meshgrid(theta, phi, indexing="ij")
    u = np.stack([np.sin(th) * np.cos(ph), np.cos(th), np.sin(th) * np.sin(ph)], -1).reshape(-1, 3)
    u = np.concatenate([[[0, 1, 0]], u, [[0, -1, 0]]])
    k = rng.normal(size=(6, 3)) * 3.0
    r = radius * (1 + 0.12 * np.sin(u @ k.T + rng.uniform(0, 6.3, 6)).sum(1) / 2)
    v = u * r[:, None]
    ring = lambda i: 1 + i * n_lon + np.arange(n_lon)   # noqa: E731
    faces = [np.stack([np.zeros(n_lon, int), ring(0)[(np.arange(n_lon) + 1) % n_lon], ring(0)], 1)]
    for i in range(n_lat - 2):
        a, b = ring(i), ring(i + 1)
        a1, b1 = np.roll(a, -1), np.roll(b, -1)
        faces += [np.stack([a, a1, b], 1), np.stack([a1, b1, b], 1)]
    last = len(v) - 1
    a = ring(n_lat - 2)
    faces.append(np.stack([a, np.roll(a, -1), np.full(n_lon, last)], 1))
    return v, np.concatenate(faces)


def table1_scene(triangles: int, lit: bool = True) -> tuple[SceneXML, bytes]:
    """(scene, PLY bytes of ``object.ply``) of the Table 1 set-up."""
    s = SceneXML(f"Lin et al. Table 1 set-up: point light in a box room, one moving "
                 f"object of {triangles} triangles")
    s.medium(Medium(sigma_t=0.08, albedo=0.9, phase=Phase("isotropic")))
    s.camera((0.0, 1.6, -4.5), (0.0, 1.3, 0.0), fov=60.0)
    s.point((0.4, 3.4, 0.8), intensity=(30.0, 28.0, 24.0))
    grey = s.bsdf("room_bsdf", (0.5, 0.5, 0.5) if lit else 0.0)
    obj = s.bsdf("object_bsdf", (0.7, 0.6, 0.5) if lit else 0.0)
    w, h, t = 3.0, 4.0, 0.2
    s.box("floor", grey, (-w - t, -t, -w - t), (w + t, 0.0, w + t))
    s.box("ceiling", grey, (-w - t, h, -w - t), (w + t, h + t, w + t))
    s.box("wall_back", grey, (-w - t, 0, w), (w + t, h, w + t))
    s.box("wall_left", grey, (-w - t, 0, -w - t), (-w, h, w))
    s.box("wall_right", grey, (w, 0, -w - t), (w + t, h, w))
    s.ply("object", obj, "object_%d.ply" % triangles)
    s.medium_box((-w - 2 * t, -2 * t, -w - 2 * t - 3.0), (w + 2 * t, h + 2 * t, w + 2 * t))
    v, f = blob_mesh(triangles, radius=0.55, seed=triangles)
    v = v + np.array([0.1, 1.5, 0.4])
    return s, ply_bytes(v, f)


def nave_swing(lit: bool = False) -> SceneXML:
    """``nave_offscreen`` with the pendulum box ``swinger`` in the shafts."""
    s = catalog.nave_offscreen(lit)
    c, half = np.array(NAVE_SWING["centre"]), NAVE_SWING["size"] / 2
    s.box("swinger", s.bsdf("swinger_bsdf", (0.6, 0.3, 0.2) if lit else 0.0), c - half, c + half)
    return s


def write_table1(directory: Path = DEFAULT_DIR, triangles=TABLE1_TRIANGLES) -> list[Path]:
    """Write ``table1_<n>.xml`` and its mesh for each size; returns the XML paths."""
    out = []
    for n in triangles:
        xml = Path(directory) / f"table1_{n}.xml"
        mesh = Path(directory) / f"object_{n}.ply"
        s, ply = table1_scene(n)
        if not mesh.exists() or mesh.read_bytes() != ply:
            write_atomic(mesh, ply)
        write_atomic(xml, s.to_string().encode("utf-8"))
        out.append(xml)
    return out


def write_nave_swing(directory: Path = DEFAULT_DIR, lit: bool = False) -> Path:
    path = Path(directory) / f"nave_swing{'_lit' if lit else ''}.xml"
    write_atomic(path, nave_swing(lit).to_string().encode("utf-8"))
    return path


if __name__ == "__main__":
    d = Path(sys.argv[1]) if len(sys.argv) > 1 else DEFAULT_DIR
    for p in write_table1(d) + [write_nave_swing(d)]:
        print(p)

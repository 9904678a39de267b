"""Procedural meshes of the suite (grove foliage, terrain) and a PLY writer.

Everything here is deterministic: each generator takes an explicit seed and
uses its own ``numpy.random.Generator``, so the same arguments give the same
bytes.  Only NumPy is needed.
"""
from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np


# ---------------------------------------------------------------------------
# PLY output
# ---------------------------------------------------------------------------
def ply_bytes(vertices: np.ndarray, faces: np.ndarray,
              normals: np.ndarray | None = None) -> bytes:
    """A binary little-endian PLY of a triangle mesh.

    ``vertices``/``normals``: (n, 3) floats, stored as float32;
    ``faces``: (m, 3) vertex indices, stored as ``list uchar int``.
    """
    vertices = np.asarray(vertices, dtype="<f4").reshape(-1, 3)
    faces = np.asarray(faces).reshape(-1, 3)
    if faces.size and (faces.min() < 0 or faces.max() >= len(vertices)):
        raise ValueError("face index out of range")
    props = ["property float x", "property float y", "property float z"]
    columns = [vertices]
    if normals is not None:
        props += ["property float nx", "property float ny", "property float nz"]
        columns.append(np.asarray(normals, dtype="<f4").reshape(-1, 3))
    header = "\n".join([
        "ply", "format binary_little_endian 1.0",
        f"element vertex {len(vertices)}", *props,
        f"element face {len(faces)}", "property list uchar int vertex_indices",
        "end_header"]) + "\n"
    vert_block = np.ascontiguousarray(np.concatenate(columns, axis=1), dtype="<f4")
    face_block = np.empty(len(faces), dtype=[("n", "u1"), ("idx", "<i4", (3,))])
    face_block["n"] = 3
    face_block["idx"] = faces
    return header.encode("ascii") + vert_block.tobytes() + face_block.tobytes()


def write_atomic(path: Path, data: bytes) -> None:
    """Write ``data`` to ``path`` via a temporary file and an atomic rename, so
    concurrent readers never see a half-written file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_bytes(data)
    os.replace(tmp, path)


# ---------------------------------------------------------------------------
# Grove: trees with clustered leaf triangles
# ---------------------------------------------------------------------------
@dataclass(frozen=True)
class Tree:
    """One tree: trunk from ``base`` up to ``top``; crown ellipsoid around
    ``crown_center`` with semi-axes ``crown_radii``."""
    base: tuple[float, float, float]
    top: tuple[float, float, float]
    trunk_radius: float
    crown_center: tuple[float, float, float]
    crown_radii: tuple[float, float, float]


def place_trees(n: int, center: tuple[float, float], radius: float,
                min_gap: float, seed: int,
                clearing: tuple[float, float, float] = (0.0, 0.0, 0.0)) -> list[Tree]:
    """``n`` trees by dart throwing in a disk (``min_gap`` apart, none
    within the ``clearing`` disk (x, z, radius)), with random heights and
    crown sizes."""
    rng = np.random.default_rng(seed)
    spots: list[np.ndarray] = []
    clear_at, clear_r = np.asarray(clearing[:2]), clearing[2]
    while len(spots) < n:
        p = np.asarray(center) + radius * np.sqrt(rng.random()) * _unit2(rng)
        if np.linalg.norm(p - clear_at) >= clear_r and \
                all(np.linalg.norm(p - q) >= min_gap for q in spots):
            spots.append(p)
    trees = []
    for x, z in spots:
        height = rng.uniform(4.0, 7.0)
        r_xz, r_y = rng.uniform(2.4, 3.3), rng.uniform(2.0, 2.8)
        trees.append(Tree(
            base=(float(x), 0.0, float(z)),
            top=(float(x), float(height), float(z)),
            trunk_radius=float(rng.uniform(0.18, 0.32)),
            crown_center=(float(x), float(height + 0.6 * r_y), float(z)),
            crown_radii=(float(r_xz), float(r_y), float(r_xz))))
    return trees


def _unit2(rng: np.random.Generator) -> np.ndarray:
    a = rng.uniform(0, 2 * np.pi)
    return np.array([np.cos(a), np.sin(a)])


def _unit3(rng: np.random.Generator, n: int) -> np.ndarray:
    v = rng.normal(size=(n, 3))
    return v / np.linalg.norm(v, axis=1, keepdims=True)


def crown_leaves(tree: Tree, clumps: int, leaves_per_clump: int,
                 clump_radius: float, leaf_size: float,
                 rng: np.random.Generator) -> np.ndarray:
    """Leaf triangles of one crown, as an (m, 3, 3) array of corner positions.

    Leaves gather in ``clumps`` spherical clusters scattered through the crown
    ellipsoid, so the crown has holes the sun can shine through.
    """
    # clump centres: uniform in the ellipsoid (shrunk so clumps stay inside)
    u = _unit3(rng, clumps) * rng.random((clumps, 1)) ** (1 / 3)
    reach = np.asarray(tree.crown_radii) - clump_radius * 0.5
    centres = np.asarray(tree.crown_center) + u * reach
    n = clumps * leaves_per_clump
    # leaf anchors: uniform in a ball around their clump centre
    offs = _unit3(rng, n) * (clump_radius * rng.random((n, 1)) ** (1 / 3))
    anchors = np.repeat(centres, leaves_per_clump, axis=0) + offs
    # each leaf: a triangle in a random plane, size jittered by +-30 %
    e1 = _unit3(rng, n)
    e2 = np.cross(e1, _unit3(rng, n))
    e2 /= np.linalg.norm(e2, axis=1, keepdims=True)
    s = leaf_size * rng.uniform(0.7, 1.3, (n, 1))
    corners = np.stack([anchors, anchors + s * e1,
                        anchors + s * (0.5 * e1 + 0.8 * e2)], axis=1)
    return corners


def grove_leaves(trees: list[Tree], leaves_per_tree: int, seed: int,
                 clump_leaves: int = 100, clump_radius: float = 0.7,
                 leaf_size: float = 0.3) -> tuple[np.ndarray, np.ndarray]:
    """All crowns as one mesh: (vertices, faces) with one triangle per leaf."""
    rng = np.random.default_rng(seed)
    clumps = max(1, leaves_per_tree // clump_leaves)
    tris = np.concatenate([crown_leaves(t, clumps, clump_leaves, clump_radius,
                                        leaf_size, rng) for t in trees])
    vertices = tris.reshape(-1, 3)
    faces = np.arange(len(vertices), dtype=np.int32).reshape(-1, 3)
    return vertices, faces


# ---------------------------------------------------------------------------
# Terrain: fBm / ridged value noise on a regular grid
# ---------------------------------------------------------------------------
def value_noise(n: int, cells: int, rng: np.random.Generator) -> np.ndarray:
    """An (n, n) array of smooth value noise in [0, 1] with ``cells`` lattice
    cells across (random lattice values, smoothstep-interpolated)."""
    lattice = rng.random((cells + 1, cells + 1))
    t = np.linspace(0.0, cells, n, endpoint=True)
    i = np.minimum(t.astype(int), cells - 1)
    f = t - i
    f = f * f * (3 - 2 * f)
    a = lattice[i][:, i] * (1 - f)[None, :] + lattice[i][:, i + 1] * f[None, :]
    b = lattice[i + 1][:, i] * (1 - f)[None, :] + lattice[i + 1][:, i + 1] * f[None, :]
    return a * (1 - f)[:, None] + b * f[:, None]


def fbm(n: int, octaves: int, base_cells: int, seed: int, ridged: bool = False,
        gain: float = 0.5) -> np.ndarray:
    """Fractal sum of ``octaves`` value-noise layers (lacunarity 2), normalised
    to [0, 1].  ``ridged`` folds each layer (1 - |2v - 1|)^2 for sharp crests."""
    rng = np.random.default_rng(seed)
    total = np.zeros((n, n))
    amp = 1.0
    for o in range(octaves):
        layer = value_noise(n, base_cells * 2 ** o, rng)
        if ridged:
            layer = (1 - np.abs(2 * layer - 1)) ** 2
        total += amp * layer
        amp *= gain
    total -= total.min()
    return total / total.max()


def grid_mesh(heights: np.ndarray, size: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A heightfield over ``[-size/2, size/2]^2`` (x, z; y up) as
    (vertices, faces, vertex normals); ``heights[i, j]`` sits at row i (z)
    and column j (x).  Two triangles per cell, counter-clockwise seen from +y."""
    n = heights.shape[0]
    coords = np.linspace(-size / 2, size / 2, n)
    x, z = np.meshgrid(coords, coords)
    vertices = np.stack([x, heights, z], axis=-1).reshape(-1, 3)
    idx = np.arange(n * n, dtype=np.int32).reshape(n, n)
    a, b = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel()
    c, d = idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, c, b], 1), np.stack([b, c, d], 1)])
    step = size / (n - 1)
    dh_dz, dh_dx = np.gradient(heights, step)
    normals = np.stack([-dh_dx, np.ones_like(heights), -dh_dz], axis=-1).reshape(-1, 3)
    normals /= np.linalg.norm(normals, axis=1, keepdims=True)
    return vertices, faces, normals


def terrain_heights(n: int, size: float, seed: int, relief: float) -> np.ndarray:
    """Mountains around a valley running along +z through x = 0.

    Ridged fBm for crests plus plain fBm for rolling ground, multiplied by a
    valley profile that is low near x = 0 and the near (-z) edge, so a camera
    at the near end looks up the valley toward ridges that shadow it.
    """
    ridges = fbm(n, octaves=7, base_cells=3, seed=seed, ridged=True)
    rolling = fbm(n, octaves=6, base_cells=4, seed=seed + 1)
    coords = np.linspace(-0.5, 0.5, n)
    x, z = np.meshgrid(coords, coords)
    valley = _smoothstep(0.05, 0.35, np.abs(x + 0.08 * np.sin(6 * z)))
    far = 0.2 + 0.8 * _smoothstep(-0.4, 0.25, z)
    mountains = (0.15 + 0.85 * valley) * far * (0.7 * ridges + 0.3 * rolling)
    return relief * mountains


def _smoothstep(e0: float, e1: float, x: np.ndarray) -> np.ndarray:
    t = np.clip((x - e0) / (e1 - e0), 0, 1)
    return t * t * (3 - 2 * t)

"""Generated assets (meshes, textures) of the scene suite.

The big meshes and the projected texture are not committed: they are built
on demand into ``scenes/meshes/`` and ``scenes/textures/`` (both git-ignored).
Each asset has a *spec* (the parameters that determine its bytes, plus a
hash of the generator source code); a JSON sidecar ``.<file>.spec.json``
records the spec it was built with, so an asset is rebuilt when it is missing
or when its parameters or generator code changed, never used stale.
"""
from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Callable

import numpy as np

from . import meshes, textures

SCENE_DIR = Path(__file__).resolve().parent

# -- parameters shared by the XML generator and the asset builders ----------
#: grove: trees placed in a disk; leaves in clumps (>= 100k triangles total)
GROVE = dict(trees=50, center=(0.0, 4.0), radius=22.0, min_gap=3.4, seed=7,
             clearing=(0.0, -10.0, 3.5), leaves_per_tree=2500, leaf_seed=8)
#: terrain: (n x n) height grid over a size x size m square (2 (n-1)^2 triangles)
TERRAIN = dict(n=725, size=1200.0, relief=260.0, seed=1234)
#: stained glass texture for the spot light
GLASS = dict(size=128, panes=28, seed=3)


@lru_cache(maxsize=None)
def grove_trees() -> tuple[meshes.Tree, ...]:
    """The grove's trees (positions, trunks, crowns)."""
    g = GROVE
    return tuple(meshes.place_trees(g["trees"], g["center"], g["radius"],
                                    g["min_gap"], g["seed"], g["clearing"]))


@lru_cache(maxsize=None)
def terrain_heights() -> np.ndarray:
    """The terrain's (n, n) height grid in meters."""
    t = TERRAIN
    return meshes.terrain_heights(t["n"], t["size"], t["seed"], t["relief"])


def terrain_height_at(x: float, z: float) -> float:
    """Terrain height at (x, z), bilinear in the grid (as the mesh is)."""
    h = terrain_heights()
    n, size = TERRAIN["n"], TERRAIN["size"]
    u = (np.array([x, z]) / size + 0.5) * (n - 1)
    j, i = np.clip(np.floor(u).astype(int), 0, n - 2)
    fx, fz = u - [j, i]
    # the grid mesh splits each cell along the (i, j+1)-(i+1, j) diagonal
    if fx + fz <= 1:
        return float(h[i, j] + fx * (h[i, j + 1] - h[i, j]) + fz * (h[i + 1, j] - h[i, j]))
    return float(h[i + 1, j + 1] + (1 - fx) * (h[i + 1, j] - h[i + 1, j + 1])
                 + (1 - fz) * (h[i, j + 1] - h[i + 1, j + 1]))


# -- builders: each returns the file's bytes ---------------------------------
def build_grove_leaves() -> bytes:
    """PLY of all leaf triangles of the grove."""
    g = GROVE
    v, f = meshes.grove_leaves(list(grove_trees()), g["leaves_per_tree"], g["leaf_seed"])
    return meshes.ply_bytes(v, f)


def build_terrain() -> bytes:
    """PLY of the terrain heightfield with smooth vertex normals."""
    v, f, n = meshes.grid_mesh(terrain_heights(), TERRAIN["size"])
    return meshes.ply_bytes(v, f, n)


def build_stained_glass() -> bytes:
    """PNG of the stained glass window."""
    g = GLASS
    return textures.png_bytes(textures.stained_glass(g["size"], g["panes"], g["seed"]))


@lru_cache(maxsize=None)
def _code_hash() -> str:
    """Hash of the modules whose code determines the assets' bytes."""
    h = hashlib.sha256()
    for module in (meshes, textures):
        h.update(Path(module.__file__).read_bytes())
    h.update(Path(__file__).read_bytes())
    return h.hexdigest()[:16]


@dataclass(frozen=True)
class Asset:
    """A generated file: ``relpath`` under ``scenes/``, its spec, its builder."""
    relpath: str
    spec: dict
    build: Callable[[], bytes]

    @property
    def path(self) -> Path:
        return SCENE_DIR / self.relpath

    @property
    def stamp(self) -> Path:
        return self.path.with_name(f".{self.path.name}.spec.json")

    def spec_text(self) -> str:
        return json.dumps({"params": self.spec, "code": _code_hash()}, sort_keys=True)

    def is_current(self) -> bool:
        """True when the file exists and was built from the current spec."""
        try:
            return self.path.is_file() and self.stamp.read_text() == self.spec_text()
        except OSError:
            return False

    def make(self) -> None:
        """Build the file and its spec stamp (atomically)."""
        meshes.write_atomic(self.path, self.build())
        meshes.write_atomic(self.stamp, self.spec_text().encode())


ASSETS = (
    Asset("meshes/grove_leaves.ply", GROVE, build_grove_leaves),
    Asset("meshes/terrain.ply", TERRAIN, build_terrain),
    Asset("textures/stained_glass.png", GLASS, build_stained_glass),
)


def ensure_assets(force: bool = False, verbose: bool = True) -> list[Path]:
    """Build every asset that is missing or out of date (all with ``force``).

    Fast (a few ``stat`` calls) when everything is current.  Returns the
    paths that were built.
    """
    built = []
    for asset in ASSETS:
        if not force and asset.is_current():
            continue
        if verbose:
            print(f"episcatter scenes: building {asset.relpath} ...", end="",
                  file=sys.stderr, flush=True)
        t0 = time.perf_counter()
        asset.make()
        if verbose:
            print(f" done ({time.perf_counter() - t0:.1f} s)", file=sys.stderr, flush=True)
        built.append(asset.path)
    return built

"""Finished chunks of a reference on disk, so an interrupted render resumes.

A reference (:mod:`episcatter.reference`) is rendered in chunks with
distinct seeds.  Each finished chunk is stored at once as
``seed<seed>-spp<spp>.npz`` in the reference's chunk folder (next to its
EXR, named after the same cache key): the chunk's float32 image exactly as
rendered, and its metadata (render seconds, which worker).  A run that was
interrupted (Ctrl-C, a killed worker, a lost scheduler) finds those files
and renders only the chunks that are missing.  Files are written under a
temporary name and renamed, so a chunk file is either complete or absent.
"""
from __future__ import annotations

import json
import os
import shutil

import numpy as np


class ChunkStore:
    """The stored chunks of one reference, in ``folder``."""

    def __init__(self, folder):
        self.folder = os.fspath(folder)

    def path(self, seed: int, spp: int) -> str:
        """File of the chunk rendered with ``seed`` and ``spp`` samples per pixel."""
        return os.path.join(self.folder, f"seed{int(seed)}-spp{int(spp)}.npz")

    def save(self, seed: int, spp: int, image, meta: dict) -> str:
        """Store one chunk's image (kept bit for bit) and metadata; returns its path."""
        os.makedirs(self.folder, exist_ok=True)
        path = self.path(seed, spp)
        tmp = f"{path}.{os.getpid()}.tmp.npz"
        np.savez(tmp, image=np.asarray(image), meta=np.array(json.dumps(meta, sort_keys=True)))
        os.replace(tmp, path)
        return path

    def load(self, seed: int, spp: int):
        """(image, meta) of a stored chunk, or None if absent or unreadable."""
        path = self.path(seed, spp)
        if not os.path.isfile(path):
            return None
        try:
            with np.load(path, allow_pickle=False) as data:
                return data["image"], json.loads(str(data["meta"]))
        except (OSError, ValueError, KeyError):
            return None

    def stored(self, plan) -> dict:
        """``{seed: (image, meta)}`` of the chunks of ``plan`` ([(seed, spp), ...]) on disk."""
        out = {}
        for seed, spp in plan:
            hit = self.load(seed, spp)
            if hit is not None:
                out[seed] = hit
        return out

    def clear(self) -> None:
        """Remove every stored chunk (and the folder)."""
        shutil.rmtree(self.folder, ignore_errors=True)

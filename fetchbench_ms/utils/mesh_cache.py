"""Content-addressed mesh files for SAPIEN.

SAPIEN's actor builders take convex and visual meshes only as files. Meshes here are
generated from numbers (procedural objects, convex furniture pieces), so they are
written once to ``$FETCHBENCH_CACHE`` (default ``~/.cache/fetchbench_ms``) under the hash
of their content and reused: the same mesh is always the same file, and a half-written
file is never visible (atomic rename).
"""
from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import trimesh

from .io import atomic_write_bytes, sha256_bytes


def cache_dir() -> Path:
    root = os.environ.get("FETCHBENCH_CACHE") or os.path.join(Path.home(), ".cache", "fetchbench_ms")
    return Path(root)


def mesh_file(mesh: trimesh.Trimesh, suffix: str = ".obj") -> str:
    """Path of a file holding ``mesh`` (vertices, faces, and vertex colours if any)."""
    vertices = np.ascontiguousarray(mesh.vertices, dtype=np.float64)
    faces = np.ascontiguousarray(mesh.faces, dtype=np.int64)
    key = sha256_bytes(vertices.tobytes() + b"|" + faces.tobytes())[:32]
    path = cache_dir() / "meshes" / f"{key}{suffix}"
    if not path.exists():
        data = trimesh.Trimesh(vertices, faces, process=False).export(file_type=suffix.lstrip("."))
        atomic_write_bytes(path, data if isinstance(data, bytes) else data.encode())
    return str(path)

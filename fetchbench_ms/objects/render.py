"""Contact sheets of catalog objects, drawn with matplotlib (CPU only, no GPU renderer).

Each object is drawn from its convex parts (what physics sees) in its most likely
stable pose, shaded by a fixed light, on a common scale so sizes compare."""
from __future__ import annotations

import math

import numpy as np

from .asset import ObjectAsset


def _shade(normals: np.ndarray, rgb: np.ndarray) -> np.ndarray:
    light = np.array([0.4, -0.5, 0.77])
    light /= np.linalg.norm(light)
    intensity = 0.35 + 0.65 * np.clip(normals @ light, 0.0, 1.0)
    return np.clip(rgb[None, :] * intensity[:, None], 0.0, 1.0)


def contact_sheet(assets: list[ObjectAsset], out_path: str, columns: int = 6, title: str | None = None) -> str:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Poly3DCollection

    from ..utils.io import atomic_write_bytes

    if not assets:
        raise ValueError("no objects to draw")
    rows = math.ceil(len(assets) / columns)
    fig = plt.figure(figsize=(2.4 * columns, 2.6 * rows + (0.4 if title else 0.0)))
    half = max(float(np.max(a.extents)) for a in assets) / 2 * 1.05
    for k, asset in enumerate(assets):
        ax = fig.add_subplot(rows, columns, k + 1, projection="3d")
        T = asset.stable_poses[0] if len(asset.stable_poses) else np.eye(4)
        rgb = np.array(asset.rgba[:3] if asset.rgba else (0.65, 0.6, 0.55))
        polys, colours = [], []
        for part in asset.convex_parts:
            moved = part.copy()
            moved.apply_transform(T)
            polys.append(moved.vertices[moved.faces])
            colours.append(_shade(moved.face_normals, rgb))
        mesh = Poly3DCollection(np.concatenate(polys), facecolors=np.concatenate(colours), edgecolors="none")
        ax.add_collection3d(mesh)
        centre = np.concatenate([p[:, 0] for p in polys]).mean(axis=0)
        ax.set_xlim(centre[0] - half, centre[0] + half)
        ax.set_ylim(centre[1] - half, centre[1] + half)
        ax.set_zlim(0.0, 2 * half)
        ax.set_box_aspect((1, 1, 1))
        ax.view_init(elev=28, azim=-55)
        ax.set_axis_off()
        e = asset.extents * 100
        ax.set_title(f"{asset.object_id.split('/', 1)[1]}\n{e[0]:.0f}x{e[1]:.0f}x{e[2]:.0f} cm", fontsize=7)
    if title:
        fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    import io

    buffer = io.BytesIO()
    fig.savefig(buffer, format="png", dpi=80)
    plt.close(fig)
    atomic_write_bytes(out_path, buffer.getvalue())
    return out_path

"""Picture of an object with its labelled grasps, drawn as simple hand outlines (CPU, matplotlib)."""
from __future__ import annotations

import io
import os

import numpy as np
import trimesh

from ..utils.io import atomic_write_bytes
from .hand import gripper_outline_hand
from .store import Grasps


def render_grasps_png(asset, grasps: Grasps, out: str | os.PathLike, max_grasps: int = 40, show_failures: bool = False,
                      rng: np.random.Generator | None = None) -> int:
    """Draw ``asset`` and up to ``max_grasps`` successful grasps (green; failures red if asked).
    Returns how many outlines were drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection, Poly3DCollection

    rng = rng if rng is not None else np.random.default_rng(0)
    # The convex parts: the shape the grasps were verified on, and light to draw (a scan's
    # visual mesh has 16k triangles).
    mesh = trimesh.util.concatenate(list(asset.convex_parts))
    faces = mesh.faces
    fig = plt.figure(figsize=(6, 6), dpi=110)
    ax = fig.add_subplot(projection="3d")
    ax.add_collection3d(Poly3DCollection(
        mesh.vertices[faces], facecolor=(0.45, 0.5, 0.75, 0.45), edgecolor=(0.3, 0.3, 0.5, 0.15), linewidths=0.2))
    drawn = 0
    groups = [(grasps.success, "tab:green")] + ([(~grasps.success, "tab:red")] if show_failures else [])
    for mask, color in groups:
        index = np.flatnonzero(mask)
        if len(index) > max_grasps:
            index = np.sort(rng.choice(index, size=max_grasps, replace=False))
        segments = []
        for i in index:
            T = grasps.T_object_hand[i]
            lines = gripper_outline_hand(max(float(grasps.width[i]), 0.01)) @ T[:3, :3].T + T[:3, 3]
            segments.extend(lines)
        if segments:
            ax.add_collection3d(Line3DCollection(np.array(segments), colors=color, linewidths=1.0))
        drawn += len(index)
    centre = mesh.bounds.mean(axis=0)
    half = mesh.extents.max() / 2 + 0.06  # the outlines reach ~0.11 m behind the TCP; most stay in view
    ax.set_xlim(centre[0] - half, centre[0] + half)
    ax.set_ylim(centre[1] - half, centre[1] + half)
    ax.set_zlim(centre[2] - half, centre[2] + half)
    rate = grasps.success.mean() if len(grasps) else 0.0
    save_3d_png(fig, ax, f"{grasps.object_id}: {int(grasps.success.sum())}/{len(grasps)} trials held ({rate:.0%})", out)
    return drawn


def save_3d_png(fig, ax, title: str, out: str | os.PathLike) -> None:
    """Equal axes in metres, the title, and the figure written as a PNG (atomically), then closed."""
    import matplotlib.pyplot as plt

    ax.set_box_aspect((1, 1, 1))
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_zlabel("z (m)")
    ax.set_title(title, fontsize=9)
    buffer = io.BytesIO()
    fig.savefig(buffer, format="png")
    plt.close(fig)
    atomic_write_bytes(out, buffer.getvalue())

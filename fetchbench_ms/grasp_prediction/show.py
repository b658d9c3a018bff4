"""``fetchbench grasps predict``: Contact-GraspNet's grasps on a suite task's observed target,
written as data (.npz / .json) and drawn on the cloud (PNG), with the inference time."""
from __future__ import annotations

import os
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

if TYPE_CHECKING:
    from .predict import PredictedGrasps


def render_predictions_png(scene: np.ndarray, target: np.ndarray, grasps: PredictedGrasps, out: str | os.PathLike,
                           top: int = 10, title: str = "", rng: np.random.Generator | None = None) -> int:
    """The points near the target (scene grey, target orange) and the ``top`` best grasps
    (hand outlines, darker = higher score). Returns how many grasps were drawn."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    from ..grasp_labels.hand import gripper_outline_hand
    from ..grasp_labels.show import save_3d_png
    from .predict import REGION_SIZE

    rng = rng if rng is not None else np.random.default_rng(0)
    centre = (np.percentile(target, 2, axis=0) + np.percentile(target, 98, axis=0)) / 2
    half = REGION_SIZE[0] / 2
    fig = plt.figure(figsize=(6, 6), dpi=110)
    ax = fig.add_subplot(projection="3d")
    for points, color, n in ((scene, "0.6", 4000), (target, "tab:orange", 1500)):
        near = points[np.all(np.abs(points - centre) <= half, axis=1)]
        if len(near) > n:
            near = near[rng.choice(len(near), size=n, replace=False)]
        ax.scatter(*near.T, s=0.5, c=color, depthshade=False)
    shown = min(top, len(grasps.scores))
    cmap = plt.get_cmap("viridis")
    for i in range(shown):
        T = grasps.T_base_hand[i]
        lines = gripper_outline_hand(max(float(grasps.widths[i]), 0.02)) @ T[:3, :3].T + T[:3, 3]
        ax.add_collection3d(Line3DCollection(lines, colors=[cmap(1.0 - grasps.scores[i])], linewidths=1.2))
    for setter, c in zip((ax.set_xlim, ax.set_ylim, ax.set_zlim), centre):
        setter(c - half, c + half)
    best = f", best score {grasps.scores[0]:.2f}" if shown else ""
    save_3d_png(fig, ax, f"{title}: {shown} of {len(grasps.scores)} grasps on the target{best}", out)
    return shown


GRASP_FILE_SUFFIXES = (".npz", ".json")


def grasps_path(png: str | os.PathLike, grasps_out: str | None) -> Path:
    """Where the grasps go: ``--grasps-out``, else beside the PNG as ``<name>.npz``."""
    path = Path(grasps_out) if grasps_out else Path(png).with_suffix(".npz")
    if path.suffix not in GRASP_FILE_SUFFIXES:
        raise ValueError(f"--grasps-out {path}: unknown format {path.suffix!r}; valid: {', '.join(GRASP_FILE_SUFFIXES)}")
    return path


def write_grasps(path: Path, grasps: PredictedGrasps, meta: dict) -> None:
    """The grasps, best first, in the robot-base frame: ``T_base_hand`` (N, 4, 4) panda_hand
    poses, ``widths`` (N,) m, ``scores`` (N,), ``contacts`` (N, 3) m; .npz (arrays, plus
    ``meta`` as a JSON string) or .json (lists, ``meta`` beside them). Written atomically."""
    import io
    import json

    from ..utils.io import atomic_write_bytes, atomic_write_text

    arrays = {"T_base_hand": grasps.T_base_hand.astype(np.float32), "widths": grasps.widths.astype(np.float32),
              "scores": grasps.scores.astype(np.float32), "contacts": grasps.contacts.astype(np.float32)}
    if path.suffix == ".npz":
        buffer = io.BytesIO()
        np.savez_compressed(buffer, **arrays, meta=np.array(json.dumps(meta, sort_keys=True)))
        atomic_write_bytes(path, buffer.getvalue())
    else:
        body = {**meta, "frame": "robot base", **{k: np.round(v.astype(float), 6).tolist() for k, v in arrays.items()}}
        atomic_write_text(path, json.dumps(body, indent=1) + "\n")


def cmd_predict(args) -> int:
    import time

    from ..envs import fetch_clouds, make
    from .predict import load_model, predict_from_clouds

    out_grasps = grasps_path(args.out, args.grasps_out)  # a bad name: before anything runs
    suite = args.task.split("/")[0] if args.suite is None else args.suite
    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite)
    try:
        obs, _ = env.reset(options={"task_id": args.task})
        clouds = fetch_clouds(obs)
    finally:
        env.close()
    t0 = time.perf_counter()
    model = load_model(args.grasp_model)
    t1 = time.perf_counter()
    grasps = predict_from_clouds(clouds, model, np.random.default_rng(args.seed))
    t2 = time.perf_counter()
    write_grasps(out_grasps, grasps, {"task_id": args.task, "grasp_model": args.grasp_model, "seed": args.seed,
                                      "grasps": int(len(grasps.scores))})
    drawn = render_predictions_png(clouds.scene, clouds.target, grasps, args.out, top=args.top,
                                   title=f"{args.task} ({args.grasp_model})")
    print(f"{len(grasps.scores)} grasps on the target of {args.task}: inference {t2 - t1:.2f} s on the CPU "
          f"(model load {t1 - t0:.2f} s)")
    print(f"wrote {out_grasps} (poses T_base_hand, widths, scores, contacts; best first) and {args.out} "
          f"(the best {drawn} drawn)")
    return 0


def add_predict_command(sub) -> None:
    p = sub.add_parser("predict", help="Contact-GraspNet's grasps on a suite task's observed target: .npz/.json and a PNG")
    p.add_argument("task", help="a suite task id, e.g. smoke/0003")
    p.add_argument("--suite", default=None, help="the suite (default: the task id's prefix)")
    p.add_argument("--out", required=True)
    p.add_argument("--grasp-model", default="pretrained", choices=("pretrained", "ours"))
    p.add_argument("--top", type=int, default=10, help="draw the best this many")
    p.add_argument("--seed", type=int, default=0, help="seed of the point sampling")
    p.add_argument("--grasps-out", default=None,
                   help="the grasps (robot-base-frame poses, widths, scores, contacts) as .npz or .json "
                        "(default: the PNG's path with .npz)")
    p.set_defaults(func=cmd_predict)

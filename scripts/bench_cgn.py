"""Contact-GraspNet figures: inference time, and grasp quality judged by the physics labeller.

    # time per prediction (20k points; batch 1 and 16), on a rendered task's target region
    python scripts/bench_cgn.py speed --device cpu --batch 1 16
    # precision of the top-1 / top-10 predictions on suite targets, judged by the labeller
    python scripts/bench_cgn.py quality --suite val --tasks 0:20 --grasp-model pretrained

``speed`` times ``predict_batch`` (farthest-point sampling + network + sigmoid, i.e. what an
episode pays per try besides rendering) after one warm-up call; ``--threads`` sets torch's
CPU threads. ``quality`` renders each task's clouds, predicts grasps on the target, turns the
best ``--top`` into the object's frame and runs them through the grasp labeller
(``fetchbench_ms.grasps.physics``, the same trial as the annotations: close, gravity, shake).
"""
from __future__ import annotations

import argparse
import json
import time

import numpy as np


def _env_and_clouds(task_id: str, suite: str):
    from fetchbench_ms.envs import fetch_clouds, make

    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite, control_mode="pd_joint_pos")
    obs, _ = env.reset(options={"task_id": task_id})
    return env, fetch_clouds(obs)


def cmd_speed(args) -> dict:
    import torch

    from fetchbench_ms.grasping import load_model
    from fetchbench_ms.grasping.predict import predict_batch, target_region

    torch.set_num_threads(args.threads)
    env, clouds = _env_and_clouds(args.task, args.task.split("/")[0])
    env.close()
    model = load_model(args.grasp_model, args.device)
    cloud = target_region(clouds.scene, clouds.target, args.points, np.random.default_rng(0))
    out = {"device": args.device, "threads": args.threads, "points": args.points, "grasp_model": args.grasp_model}
    for batch in args.batch:
        points = np.repeat(cloud.points[None], batch, axis=0)
        predict_batch(model, points, args.device)  # warm-up
        times = []
        for _ in range(args.repeats):
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            t = time.perf_counter()
            predict_batch(model, points, args.device)
            if args.device.startswith("cuda"):
                torch.cuda.synchronize()
            times.append(time.perf_counter() - t)
        out[f"batch_{batch}_s"] = round(float(np.median(times)), 4)
        out[f"batch_{batch}_per_cloud_s"] = round(float(np.median(times)) / batch, 4)
    return out


def cmd_quality(args) -> dict:
    import torch

    from fetchbench_ms.evaluation.runner import open_suite, parse_range
    from fetchbench_ms.envs import fetch_clouds, make
    from fetchbench_ms.grasping import predict_from_clouds
    from fetchbench_ms.grasps.physics import GraspLabeller
    from fetchbench_ms.solutions.worlds import object_poses_base
    from fetchbench_ms.tasks.objects import load_object

    torch.set_num_threads(args.threads)
    suite, _, _ = open_suite(args.suite)
    ids = list(suite.tasks)
    selection = [ids[k] for k in parse_range(args.tasks, len(ids))]
    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=args.suite, control_mode="pd_joint_pos")
    rows = []
    labeller = None
    for task_id in selection:
        obs, _ = env.reset(options={"task_id": task_id})
        task = env.unwrapped.tasks[0]
        clouds = fetch_clouds(obs)
        if len(clouds.target) == 0:
            rows.append({"task_id": task_id, "predicted": 0})
            continue
        t = time.perf_counter()
        grasps = predict_from_clouds(clouds, args.grasp_model, np.random.default_rng(0))
        seconds = time.perf_counter() - t
        T_base_object = object_poses_base(env)[task.target_index]
        T_object_hand = np.linalg.inv(T_base_object)[None] @ grasps.T_base_hand[: args.top]
        if labeller is None:  # after the env: the labeller sets PhysX's global contact settings
            labeller = GraspLabeller()
        success = labeller.label(load_object(task.target.object_id), T_object_hand).success if len(T_object_hand) else []
        rows.append({"task_id": task_id, "category": task.target_label, "predicted": len(grasps.scores),
                     "success": [bool(s) for s in success], "seconds": round(seconds, 2)})
        print(json.dumps(rows[-1]), flush=True)
    env.close()
    judged = [r for r in rows if r.get("success")]
    return {
        "suite": args.suite, "tasks": args.tasks, "grasp_model": args.grasp_model, "top": args.top,
        "tasks_run": len(rows), "tasks_with_predictions": len(judged),
        "precision_top1": round(float(np.mean([r["success"][0] for r in judged])), 3) if judged else None,
        f"precision_top{args.top}": round(float(np.mean([s for r in judged for s in r["success"]])), 3) if judged else None,
        "any_success_in_top": round(float(np.mean([any(r["success"]) for r in judged])), 3) if judged else None,
        "median_predict_s": float(np.median([r["seconds"] for r in judged])) if judged else None,
    }


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    s = sub.add_parser("speed", help="time per prediction")
    s.add_argument("--task", default="smoke/0003", help="the suite task whose target region is timed")
    s.add_argument("--points", type=int, default=20000)
    s.add_argument("--batch", type=int, nargs="+", default=[1])
    s.add_argument("--repeats", type=int, default=3)
    s.add_argument("--device", default="cpu")
    s.set_defaults(func=cmd_speed)
    q = sub.add_parser("quality", help="top-k precision judged by the physics grasp labeller")
    q.add_argument("--suite", default="val")
    q.add_argument("--tasks", default="0:20", help="START:END of the suite's tasks")
    q.add_argument("--top", type=int, default=10)
    q.set_defaults(func=cmd_quality)
    for p in (s, q):
        p.add_argument("--grasp-model", default="pretrained", choices=("pretrained", "ours"))
        p.add_argument("--threads", type=int, default=1,
                       help="torch CPU threads (episodes use 1: solve() sets it; on a loaded machine more threads are slower)")
    args = ap.parse_args(argv)
    print(json.dumps(args.func(args)))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())

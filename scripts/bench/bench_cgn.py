"""Contact-GraspNet figures: inference time, and grasp quality judged by the physics labeller.

    # time per prediction (20k points; batch 1 and 16) on the shipped cloud, no rendering
    python scripts/bench/bench_cgn.py speed --device cuda cpu --batch 1 16 --threads 4
    # (re)make that cloud: smoke/0003's target region
    python scripts/bench/bench_cgn.py save-cloud --task smoke/0003
    # precision of the top-1 / top-10 predictions on suite targets, judged by the labeller
    python scripts/bench/bench_cgn.py quality --suite val --tasks 0:20 --grasp-model pretrained

``speed`` times ``predict_batch`` (points to the device, farthest-point sampling, network,
sigmoid, results back to numpy: what an episode pays per try besides rendering) on a saved
target region (``assets/clouds/cgn_smoke_0003_region.npz``) repeated to the batch size:
the median of ``--repeats`` calls after ``--warmup`` calls on CUDA (``--cpu-repeats``,
``--cpu-warmup`` on the CPU), per device; ``--threads`` sets torch's CPU threads. On
CUDA each ``--fps`` choice is timed: the Triton farthest-point kernel (``auto``; the row
says ``"fps": "torch"`` if it failed its check and the loop ran) and the torch loop; the CPU
row says ``"numpy"`` (its sampler).

``quality`` renders each task's clouds, predicts grasps on the target, turns the best
``--top`` into the object's frame and runs them through the grasp labeller
(``fetchbench_ms.grasp_labels.physics``, the same trial as the annotations: close, gravity,
shake), and measures the coverage of the target's annotated successful grasps
(``fetchbench_ms.grasp_prediction.metrics.grasp_coverage``: those with a prediction of score
>= ``--coverage-score`` whose TCP is within 2 cm and approach within 30 deg; annotated
grasps on the unseen side count too). It is how weights and settings are compared, so it
runs on ``val`` (the default); the test suite (or a suite of its tasks, such as ``smoke``)
is refused with exit status 2 unless ``--report-only`` says that the figures are a report on
test-split objects of weights already chosen, never used to choose anything (training
validates on held-out train-split objects: baselines/contact_graspnet/train.py); the
summary then records ``"report_only": true``.
"""
from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

import numpy as np

# The target region (20k points, robot-base frame) of smoke/0003, a mug on a desk: what
# `speed` times, so that timing needs no rendering (`save-cloud` writes it).
DEFAULT_CLOUD = Path(__file__).resolve().parents[2] / "assets" / "clouds" / "cgn_smoke_0003_region.npz"


def _env_and_clouds(task_id: str, suite: str):
    from fetchbench_ms.envs import fetch_clouds, make

    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=suite, control_mode="pd_joint_pos")
    obs, _ = env.reset(options={"task_id": task_id})
    return env, fetch_clouds(obs)


def cmd_save_cloud(args) -> dict:
    """Render a task once and save its target region (what the network reads) for ``speed``."""
    from pathlib import Path

    from fetchbench_ms.grasp_prediction.predict import target_region

    env, clouds = _env_and_clouds(args.task, args.task.split("/")[0])
    env.close()
    cloud = target_region(clouds.scene, clouds.target, args.points, np.random.default_rng(0))
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.stem + ".tmp.npz")
    np.savez_compressed(tmp, points_base=cloud.points.astype(np.float32), is_target=cloud.is_target, task=args.task)
    tmp.replace(out)
    return {"saved": str(out), "task": args.task, "points": len(cloud.points), "target_points": int(cloud.is_target.sum())}


def _timing_model(name: str, device: str):
    """The weight set's network, or (when its weights are not installed) the same network
    with random weights: the cost does not depend on the weights."""
    from fetchbench_ms.grasp_prediction import load_model
    from fetchbench_ms.grasp_prediction.network import ContactGraspNet

    try:
        return load_model(name, device), name
    except FileNotFoundError as error:
        print(f"# {error}; timing randomly initialised weights instead", flush=True)
        return ContactGraspNet().eval().to(device), "random-init"


def cmd_speed(args) -> dict:
    """Median time of ``predict_batch`` (points to scores and frames back in numpy) on the saved
    cloud repeated ``batch`` times, after warm-up calls, per device and batch size."""
    import platform

    import torch

    from fetchbench_ms.geometry.pointops import fps_backend
    from fetchbench_ms.grasp_prediction.predict import predict_batch

    torch.set_num_threads(args.threads)
    saved = np.load(args.cloud)
    cloud = saved["points_base"][: args.points]
    out = {"cloud": args.cloud, "task": str(saved["task"]), "points": len(cloud), "threads": args.threads,
           "torch": torch.__version__, "cpu": platform.processor() or platform.machine(), "results": []}
    runs = [(d, f) for d in args.device for f in (args.fps if d.startswith("cuda") else ["torch"])]
    for device, fps in runs:
        if device.startswith("cuda") and not torch.cuda.is_available():
            raise SystemExit(f"--device {device}: CUDA is not available here (valid: cpu)")
        os.environ["FETCHBENCH_FPS"] = fps
        backend = fps_backend(torch.device(device)) if device.startswith("cuda") else "numpy"  # pointops: the CPU's loop
        model, weights = _timing_model(args.grasp_model, device)
        repeats = args.repeats if device.startswith("cuda") else args.cpu_repeats
        for batch in args.batch:
            points = np.repeat(cloud[None], batch, axis=0)
            for _ in range(args.warmup if device.startswith("cuda") else args.cpu_warmup):
                predict_batch(model, points, device)
            times = []
            for _ in range(repeats):
                if device.startswith("cuda"):
                    torch.cuda.synchronize()
                t = time.perf_counter()
                predict_batch(model, points, device)
                if device.startswith("cuda"):
                    torch.cuda.synchronize()
                times.append(time.perf_counter() - t)
            row = {"device": torch.cuda.get_device_name(device) if device.startswith("cuda") else f"cpu x{args.threads}",
                   "weights": weights, "fps": backend, "batch": batch, "repeats": repeats,
                   "median_s": round(float(np.median(times)), 4), "per_cloud_s": round(float(np.median(times)) / batch, 4),
                   "min_s": round(float(np.min(times)), 4)}
            print(json.dumps(row), flush=True)
            out["results"].append(row)
            if args.json_out:  # after every row: a run cut short still leaves what it measured
                write_json(out, args.json_out)
    return out


def cmd_quality(args) -> dict:
    import torch

    from fetchbench_ms.tasks.splits import cli_guard, refuse_test

    if not args.report_only:  # comparing weights or settings: never on test tasks
        cli_guard(refuse_test, args.suite, "grasp-quality comparison (bench_cgn.py quality without --report-only)")

    from fetchbench_ms.envs import make
    from fetchbench_ms.evaluation.grasp_quality import COVERAGE_RULE, QualityJudge, summarize_quality
    from fetchbench_ms.evaluation.runner import open_suite, parse_range

    torch.set_num_threads(args.threads)
    suite, _, _ = open_suite(args.suite)
    ids = list(suite.tasks)
    selection = [ids[k] for k in parse_range(args.tasks, len(ids))]
    env = make("FetchBench-v0", obs_mode="pointcloud", task_suite=args.suite, control_mode="pd_joint_pos")
    judge = QualityJudge(env, args.top, args.coverage_score)
    rows = []
    for task_id in selection:
        rows.append(judge(task_id, args.grasp_model))
        if rows[-1]["predicted"]:
            print(json.dumps(rows[-1]), flush=True)
    env.close()
    return {"suite": args.suite, "tasks": args.tasks, "grasp_model": args.grasp_model, "top": args.top,
            **summarize_quality(rows, args.top), "coverage_rule": COVERAGE_RULE.format(score=args.coverage_score),
            "report_only": bool(args.report_only)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    sub = ap.add_subparsers(dest="command", required=True)
    s = sub.add_parser("speed", help="time per prediction on a saved cloud (no rendering)")
    s.add_argument("--cloud", default=str(DEFAULT_CLOUD), help="an .npz written by save-cloud")
    s.add_argument("--points", type=int, default=20000)
    s.add_argument("--batch", type=int, nargs="+", default=[1, 16])
    s.add_argument("--device", nargs="+", default=["cpu"], help="cpu and/or cuda")
    s.add_argument("--fps", nargs="+", default=["auto", "torch"], choices=("auto", "torch"),
                   help="farthest-point sampling on CUDA: auto (the Triton kernel where it passes its check) and/or "
                        "torch (the loop); the CPU always runs the loop")
    s.add_argument("--warmup", type=int, default=2, help="untimed calls per batch size on CUDA")
    s.add_argument("--cpu-warmup", type=int, default=1, help="untimed calls per batch size on the CPU")
    s.add_argument("--repeats", type=int, default=20, help="timed calls per batch size on CUDA")
    s.add_argument("--cpu-repeats", type=int, default=3, help="timed calls per batch size on the CPU")
    s.set_defaults(func=cmd_speed)
    c = sub.add_parser("save-cloud", help="render a task once and save its target region for speed")
    c.add_argument("--task", default="smoke/0003")
    c.add_argument("--points", type=int, default=20000)
    c.add_argument("--out", default=str(DEFAULT_CLOUD))
    c.set_defaults(func=cmd_save_cloud, grasp_model="pretrained", threads=1)
    q = sub.add_parser("quality", help="top-k precision judged by the physics grasp labeller")
    q.add_argument("--suite", default="val")
    q.add_argument("--tasks", default="0:20", help="START:END of the suite's tasks")
    q.add_argument("--top", type=int, default=10)
    q.add_argument("--coverage-score", type=float, default=0.5,
                   help="predictions at least this confident count for the coverage of the annotated grasps")
    q.add_argument("--report-only", action="store_true",
                   help="the figures report weights already chosen and choose nothing: the only way to run the test "
                        "suite (refused otherwise)")
    q.set_defaults(func=cmd_quality)
    for p in (s, q):  # (save-cloud needs neither)
        p.add_argument("--grasp-model", default="pretrained", choices=("pretrained", "ours"))
        p.add_argument("--threads", type=int, default=1,
                       help="torch CPU threads (episodes use 1: solve() sets it; on a loaded machine more threads are slower)")
        p.add_argument("--json", dest="json_out", help="also write the summary JSON to this file")
    args = ap.parse_args(argv)
    summary = args.func(args)
    print(json.dumps(summary))
    if getattr(args, "json_out", None):
        write_json(summary, args.json_out)
    return 0


def write_json(summary: dict, path: str) -> None:
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(out.name + ".tmp")
    tmp.write_text(json.dumps(summary, indent=1) + "\n")
    tmp.replace(out)


if __name__ == "__main__":
    raise SystemExit(main())

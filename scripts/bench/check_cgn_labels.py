"""Check Contact-GraspNet training labels against the pretrained model's predictions.

The trainer (baselines/contact_graspnet/train.py) turns our physics-verified grasps into
CGN labels: per cloud point near a finger contact, a gripper frame (baseline x, approach z)
and a width. If those labels follow the conventions the pretrained cgn-pytorch weights were
trained with, the pretrained model (0.95 physics-judged top-1 precision on held-out objects)
predicts, at points our labels call positive, grasps close to the labelled ones: a flipped
approach, a baseline from the wrong finger, a width off by 2 or a depth offset shows up here
as a systematic error. Views are made exactly as the trainer makes them (make_scene,
render_view), of held-out train-split objects only (the trainer's validation objects).

    python scripts/bench/check_cgn_labels.py --views 6 [--objects 3] [--json out.json]

Prints, over the labelled positive contact points (the 2,048 farthest-point samples the
network predicts at): angles between predicted and labelled approach / baseline vectors,
the width difference, and the hand-pose error of the implied grasp (grasp_frames) against
the labelled one, for the label the trainer assigns and for the best of all annotated
grasps with a finger contact within the positive radius; then the trainer's losses on the
pretrained model's outputs, and the pose agreement of the pretrained top-10 grasps.
"""
from __future__ import annotations

import argparse
import importlib.util
import json
import sys
from pathlib import Path

import numpy as np
import torch

from fetchbench_ms.tasks.splits import cli_guard

ROOT = Path(__file__).resolve().parents[2]


def load_trainer():
    path = ROOT / "baselines" / "contact_graspnet" / "train.py"
    spec = importlib.util.spec_from_file_location("cgn_train", path)
    module = importlib.util.module_from_spec(spec)
    sys.modules["cgn_train"] = module
    spec.loader.exec_module(module)
    return module


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    cos = np.sum(a * b, -1) / (np.linalg.norm(a, axis=-1) * np.linalg.norm(b, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1, 1)))


def rotation_deg(Ra: np.ndarray, Rb: np.ndarray) -> np.ndarray:
    trace = np.einsum("...ij,...ij->...", Ra, Rb)  # trace(Ra^T Rb)
    return np.degrees(np.arccos(np.clip((trace - 1) / 2, -1, 1)))


def summary(x: np.ndarray) -> dict:
    x = np.asarray(x, dtype=np.float64)
    if x.size == 0:
        return {"n": 0}
    return {"n": int(x.size), "median": round(float(np.median(x)), 4), "mean": round(float(x.mean()), 4),
            "p10": round(float(np.percentile(x, 10)), 4), "p90": round(float(np.percentile(x, 90)), 4)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--views", type=int, default=6)
    parser.add_argument("--objects", type=int, default=1, help="objects per view")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--model", default="pretrained", help="pretrained, ours, or a path to a trainer checkpoint.pt")
    parser.add_argument("--json", default=None)
    cli = parser.parse_args()

    from scipy.spatial import cKDTree

    from fetchbench_ms.grasp_prediction.network import GRIPPER_DEPTH, CGNConfig, ContactGraspNet
    from fetchbench_ms.geometry.pointops import farthest_point_sample
    from fetchbench_ms.grasp_prediction.predict import load_model

    train = load_trainer()
    args = train.Args()
    # held-out train-split objects only; a test-split object is refused (exit 2)
    _, val_ids = cli_guard(train.train_val_objects, args.val_fraction)
    torch.set_num_threads(1)
    if cli.model in ("pretrained", "ours"):
        model = load_model(cli.model)
    else:  # a trainer run's checkpoint.pt (full-size network)
        model = ContactGraspNet(CGNConfig())
        model.load_state_dict(torch.load(cli.model, map_location="cpu", weights_only=False)["model"])
        model.eval()
    rng = np.random.default_rng(cli.seed)
    flip = np.diag([-1.0, -1, 1, 1])  # the gripper turned half about its approach: the same grasp
    rows: dict[str, list] = {k: [] for k in ("approach", "baseline", "baseline_mod_sign", "width_diff", "width_ratio",
                                             "hand_t", "hand_rot", "best_approach", "best_hand_t", "best_hand_rot",
                                             "top10_t", "top10_rot", "top10_approach", "top10_label_positive",
                                             "approach_dot_to_object", "confident_approach", "confident_baseline_mod_sign",
                                             "confident_width_diff", "confident_depth_offset", "confident_hand_t",
                                             "confident_hand_rot")}
    loss_rows = []
    for v in range(cli.views):
        ids = list(rng.choice(val_ids, size=cli.objects, replace=False))
        scene = train.make_scene(ids, rng)
        view = train.render_view(scene, rng, args.num_points, args.positive_radius)
        points = torch.as_tensor(view["points"][None])
        index = farthest_point_sample(points, 2048)
        with torch.no_grad():
            out = model(points, index)
        batch = {k: torch.as_tensor(view[k][None]) for k in ("points", "positive", "grasp", "width")}
        batch["grasp"][..., 3, 3] = 1.0
        parts = {**train.losses(out, batch, index, args), **train.pose_agreement(out, batch)}
        loss_rows.append({k: float(x) for k, x in parts.items()})
        idx = index[0].numpy()
        positive = view["positive"][idx]
        T_pred = out["T_grasp"][0].numpy().astype(np.float64)
        w_pred = out["width"][0].numpy()
        T_label = view["grasp"][idx].astype(np.float64)
        T_label[:, 3, 3] = 1
        w_label = view["width"][idx]
        p = positive
        a_pred, a_lab = T_pred[p, :3, 2], T_label[p, :3, 2]
        b_pred, b_lab = T_pred[p, :3, 0], T_label[p, :3, 0]
        rows["approach"] += list(angle_deg(a_pred, a_lab))
        rows["baseline"] += list(angle_deg(b_pred, b_lab))
        ab = angle_deg(b_pred, b_lab)
        rows["baseline_mod_sign"] += list(np.minimum(ab, 180 - ab))
        rows["width_diff"] += list(w_pred[p] - w_label[p])
        rows["width_ratio"] += list(w_pred[p] / np.maximum(w_label[p], 1e-4))
        # hand poses (grasp_frames of the prediction vs the label), min over the finger flip
        t_err = np.minimum(np.linalg.norm(T_pred[p, :3, 3] - T_label[p, :3, 3], axis=-1),
                           np.linalg.norm(T_pred[p, :3, 3] - (T_label[p] @ flip)[:, :3, 3], axis=-1))
        r_err = np.minimum(rotation_deg(T_pred[p, :3, :3], T_label[p, :3, :3]),
                           rotation_deg(T_pred[p, :3, :3], (T_label[p] @ flip)[:, :3, :3]))
        rows["hand_t"] += list(t_err)
        rows["hand_rot"] += list(r_err)
        # where the pretrained model is confident (score > 0.5): the grasps it would act on
        scores_p = torch.sigmoid(out["logits"][0]).numpy()[p]
        c = scores_p > 0.5
        rows["confident_approach"] += list(angle_deg(a_pred, a_lab)[c])
        rows["confident_baseline_mod_sign"] += list(np.minimum(ab, 180 - ab)[c])
        rows["confident_width_diff"] += list((w_pred[p] - w_label[p])[c])
        # hand origin offset along the labelled approach (a depth convention error shows here)
        rows["confident_depth_offset"] += list(np.sum((T_pred[p, :3, 3] - T_label[p, :3, 3]) * a_lab, -1)[c])
        rows["confident_hand_t"] += list(t_err[c])
        rows["confident_hand_rot"] += list(r_err[c])
        # the approach should point into the object: from the hand origin towards the contact
        contact = view["points"][idx][p]
        to_contact = contact - T_label[p, :3, 3]
        rows["approach_dot_to_object"] += list(np.sum(to_contact * a_lab, -1) / np.linalg.norm(to_contact, axis=-1))
        # best of all annotated grasps with a finger contact within the positive radius
        shift = view["mean"]
        contacts_view = scene["contacts"] - shift
        labels_view = scene["labels"].copy()
        labels_view[:, :3, 3] -= shift
        tree = cKDTree(contacts_view)
        for k, c in zip(np.flatnonzero(p), contact):
            near = tree.query_ball_point(c, args.positive_radius)
            if not near:
                continue
            L = labels_view[near]
            Lf = L @ flip
            t = np.minimum(np.linalg.norm(L[:, :3, 3] - T_pred[k, :3, 3], axis=-1),
                           np.linalg.norm(Lf[:, :3, 3] - T_pred[k, :3, 3], axis=-1))
            r = np.minimum(rotation_deg(L[:, :3, :3], T_pred[k, :3, :3]), rotation_deg(Lf[:, :3, :3], T_pred[k, :3, :3]))
            a = angle_deg(L[:, :3, 2], T_pred[k, :3, 2])
            rows["best_approach"].append(a.min())
            j = np.argmin(t / 0.01 + r / 10)
            rows["best_hand_t"].append(t[j])
            rows["best_hand_rot"].append(r[j])
        # the pretrained top-10 on object points: nearest annotated grasp (TCP distance, rotation)
        on_object = view["owner"][idx] >= 0
        scores = out["logits"][0].numpy()
        order = np.argsort(-np.where(on_object, scores, -np.inf))[:10]
        tcp_lab = labels_view[:, :3, 3] + GRIPPER_DEPTH * labels_view[:, :3, 2]
        for k in order:
            tcp = T_pred[k, :3, 3] + GRIPPER_DEPTH * T_pred[k, :3, 2]
            d = np.linalg.norm(tcp_lab - tcp, axis=-1)
            r = np.minimum(rotation_deg(labels_view[:, :3, :3], T_pred[k, :3, :3]),
                           rotation_deg((labels_view @ flip)[:, :3, :3], T_pred[k, :3, :3]))
            j = np.argmin(d / 0.01 + r / 10)
            rows["top10_t"].append(d[j])
            rows["top10_rot"].append(r[j])
            rows["top10_approach"].append(angle_deg(labels_view[j, :3, 2], T_pred[k, :3, 2]))
            rows["top10_label_positive"].append(float(positive[k]))
        print(f"view {v}: {ids} positives at contacts {int(p.sum())}/2048, losses "
              + " ".join(f"{k} {x:.4f}" for k, x in loss_rows[-1].items()), flush=True)
    report = {"model": cli.model, "views": cli.views, "objects": cli.objects,
              **{k: summary(x) for k, x in rows.items()},
              "losses": {k: round(float(np.mean([r[k] for r in loss_rows])), 5) for k in loss_rows[0]}}
    print(json.dumps(report, indent=1))
    if cli.json:
        Path(cli.json).write_text(json.dumps(report, indent=1) + "\n")


if __name__ == "__main__":
    main()

"""Train the scene-collision network (``fetchbench_ms.planning.collision_net``) on the
labelled queries of ``labels.py``.

One readable file in the style of CleanRL / ManiSkill's baselines: the arguments are the
dataclass below (tyro flags), then data, loss, validation, loop. The network is the
package's; only training lives here.

Data: ``--data`` (train-suite tasks) for training, ``--val`` (held-out tasks: the ``val``
suite, other scenes, train-split objects) for the validation figures and nothing else; the
test suite is never read here (``scripts/bench/bench_collision_net.py`` measures on it).
Each step takes ``--scenes`` tasks, encodes their grids, and ``--queries`` of each task's
labelled configurations (spheres by FK on the device).

Loss per step: every checked sphere's predicted clearance against its exact clearance
(smooth L1 in mm-scale, weighted up near contact), plus the query's collision label
(binary cross-entropy of ``-min clearance / TAU``).

    # on the GPU node (resumable: each call stops at --time-limit with a checkpoint; the same
    # command continues; the last call exports)
    python baselines/mppi_collision/train.py --data /tmp/mppi/train --val /tmp/mppi/val --run /tmp/mppi/run \\
        --device cuda --steps 6000 --time-limit 540 --export
    # a round (scripts/grasp_round.py): on from the shipped weights, the candidate exported
    # beside the run, not shipped; and the shipped network judged on the same val queries
    python baselines/mppi_collision/train.py --data R/train --val R/val --run R/run --init-from shipped --steps 2000 \
        --export --export-path R/export/collision_net.pt
    python baselines/mppi_collision/train.py --val R/val --judge shipped --judge-out R/val/collision_shipped.json
    # a CPU smoke run
    python baselines/mppi_collision/train.py --data /tmp/mppi/val_probe --val /tmp/mppi/val_probe --run /tmp/mppi/smoke \\
        --device cpu --steps 20 --scenes 1 --queries 256
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from fetchbench_ms.planning.collision_net import (CLEARANCE_CLIP, TAU, NetConfig, RobotSpheres, SceneCollisionNet,
                                                  checkpoint_path, grid_from_uint8, save_checkpoint)
from fetchbench_ms.tasks.splits import cli_guard, refuse_test, refuse_test_task_ids


@dataclass
class Args:
    data: str = "/tmp/mppi/train"  # labels.py output of training tasks
    val: str = "/tmp/mppi/val"  # labels.py output of held-out tasks (validation figures only)
    run: str = "runs/mppi_collision"  # log, checkpoint (re-running resumes)
    device: str = "cuda" if torch.cuda.is_available() else "cpu"
    seed: int = 0
    steps: int = 6000
    scenes: int = 8  # tasks per step
    queries: int = 512  # labelled configurations per task and step
    lr: float = 2e-3
    lr_final: float = 2e-5  # cosine decay to this
    weight_decay: float = 1e-4
    cls_weight: float = 0.2  # the query label's BCE next to the sphere regression
    channels: tuple[int, int, int] = (16, 32, 64)
    hidden: int = 64
    amp: bool = True  # bf16 autocast on CUDA
    time_limit: float = 0.0  # s; > 0: checkpoint and stop after this long (re-run to resume)
    log_every: int = 50
    ckpt_every: int = 500
    val_every: int = 1000
    val_queries: int = 2000  # per validation task
    export: bool = False  # when the last step is done: assets/checkpoints/collision_net.{pt,json} (and --export-dir)
    false_free_target: float = 0.02  # the decision margin is chosen on val for at most this false-free rate
    export_dir: str = ""  # also copy the checkpoint, JSON and log here
    # the weights to go on from (a checkpoint, packed or plain: "shipped" is assets/checkpoints/
    # collision_net.pt); its network's channels and hidden width are kept; the optimiser starts anew
    init_from: str = ""
    # --export writes here instead of assets/checkpoints/collision_net.pt (a candidate, not shipped)
    export_path: str = ""
    # judge this checkpoint on --val (every query, at clearance 0 and at its own margin), write
    # the figures to --judge-out and exit: nothing is trained
    judge: str = ""
    judge_out: str = ""


# -- data ---------------------------------------------------------------------------------
def refuse_test_labels(folders: list[str]) -> None:
    """Labels of test-suite tasks are never trained or validated on: each file's suite and
    task id (``labels.py`` records both), checked before anything is written (exit 2)."""
    for folder in folders:
        for f in sorted(Path(folder).glob("*.npz")):
            if f.name.endswith(".tmp.npz"):
                continue
            with np.load(f) as z:
                cli_guard(refuse_test, str(z["suite"]), "collision-net training")
                cli_guard(refuse_test_task_ids, [str(z["task_id"])], "collision-net training")


class Tasks:
    """All tasks of a labels folder, on the device: grids (uint8), queries and labels."""

    def __init__(self, folder: str, device):
        files = sorted(Path(folder).glob("*.npz"))
        files = [f for f in files if not f.name.endswith(".tmp.npz")]
        if not files:
            raise SystemExit(f"no labelled tasks in {folder}: run baselines/mppi_collision/labels.py first")
        h = hashlib.sha256()
        grids, q, mm, label, checked, radii, att, ids = [], [], [], [], [], [], [], []
        for f in files:
            z = np.load(f)
            h.update(f.name.encode())
            for key in ("q", "clearance_mm", "label", "grid"):
                h.update(np.ascontiguousarray(z[key]).tobytes())
            cli_guard(refuse_test, str(z["suite"]), "collision-net training")  # (checked before the run too)
            grids.append(z["grid"])
            q.append(z["q"])
            mm.append(z["clearance_mm"])
            label.append(z["label"])
            checked.append(z["checked"])
            radii.append(z["radii"])
            att.append(z["att_centers_hand"])
            ids.append(str(z["task_id"]))
        k = min(len(x) for x in q)  # queries per task (labels.py writes the same number)
        t = lambda xs, dt=None: torch.as_tensor(np.stack([x[:k] if x.ndim and len(x) > k else x for x in xs]),
                                                device=device, dtype=dt)
        self.grids = torch.as_tensor(np.stack(grids), device=device)  # (T, X, Y, Z) uint8
        self.q, self.mm, self.label = t(q, torch.float32), t(mm), t(label).bool()
        self.checked, self.radii = t(checked).bool(), t(radii, torch.float32)
        self.att = t(att, torch.float32)
        self.ids, self.hash, self.n, self.k = ids, h.hexdigest(), len(files), k

    def batch(self, tasks: torch.Tensor, idx: torch.Tensor) -> dict:
        """Queries ``idx`` (S, B) of tasks ``tasks`` (S,)."""
        rows = tasks[:, None]
        return dict(grid=grid_from_uint8(self.grids[tasks]), q=self.q[rows, idx], mm=self.mm[rows, idx].float(),
                    label=self.label[rows, idx], checked=self.checked[tasks], radii=self.radii[tasks],
                    att=self.att[tasks])


def forward(model: SceneCollisionNet, spheres: RobotSpheres, b: dict) -> torch.Tensor:
    """(S, B, 141) predicted sphere clearances (m) of a batch."""
    centers = spheres.centers(b["q"], 0.04, b["att"])  # (S, B, 141, 3)
    scene = model.encode(b["grid"])
    return model.sphere_clearance(scene, centers, b["radii"][:, None].expand(centers.shape[:-1]))


def loss_fn(pred: torch.Tensor, b: dict, args: Args) -> tuple[torch.Tensor, dict]:
    target = b["mm"] / 1000  # m, clipped to CLEARANCE_CLIP by the labels
    checked = b["checked"][:, None].expand_as(pred)
    # Near contact matters: weight 1 far away, up to 5 at contact.
    weight = (1 + 4 * torch.exp(-target.clamp(min=0) / 0.01)) * checked
    reg = (F.smooth_l1_loss(pred / 0.01, target / 0.01, beta=0.5, reduction="none") * weight).sum() / weight.sum()
    q_clear = torch.where(checked, pred, torch.full_like(pred, CLEARANCE_CLIP[1])).amin(dim=-1)
    cls = F.binary_cross_entropy_with_logits(-q_clear / TAU, b["label"].float())
    return reg + args.cls_weight * cls, dict(reg=float(reg.detach()), cls=float(cls.detach()))


def confusion(pred_collide: np.ndarray, label: np.ndarray) -> dict:
    """Accuracy, precision / recall of "collides", and the false-free rates."""
    tp = int((pred_collide & label).sum())
    fp = int((pred_collide & ~label).sum())
    fn = int((~pred_collide & label).sum())
    tn = int((~pred_collide & ~label).sum())
    n = max(1, tp + fp + fn + tn)
    return dict(n=n, accuracy=(tp + tn) / n, precision=tp / max(1, tp + fp), recall=tp / max(1, tp + fn),
                # of the queries called free, the share that collide (what a planner trusts), and of all queries
                false_free_of_free=fn / max(1, fn + tn), false_free_of_all=fn / n, collide_share=(tp + fn) / n)


def calibrate(clearance: np.ndarray, label: np.ndarray, target: float) -> float:
    """The smallest decision margin (m, 0.5 mm steps up to 3 cm) at which at most ``target``
    of the queries called free collide."""
    for margin in np.arange(0.0, 0.0305, 0.0005):
        if confusion(clearance < margin, label)["false_free_of_free"] <= target:
            return float(margin)
    return 0.03


@torch.no_grad()
def evaluate(model: SceneCollisionNet, spheres: RobotSpheres, data: Tasks, n_queries: int,
             false_free_target: float | None = None) -> dict:
    """Figures over the first ``n_queries`` of every task, with the cloud-only distance
    field (``distance - radius < 0``, what the Ptd planners see) beside the network: at
    clearance 0 and at the model's decision margin; ``false_free_target``: first choose that
    margin (validation tasks only)."""
    model.eval()
    preds, cloud, labels = [], [], []
    for i in range(data.n):
        tasks = torch.tensor([i], device=data.q.device)
        for idx in torch.arange(min(n_queries, data.k), device=data.q.device).split(1000):
            b = data.batch(tasks, idx[None])
            centers = spheres.centers(b["q"], 0.04, b["att"])
            scene = model.encode(b["grid"])
            r = b["radii"][:, None].expand(centers.shape[:-1])
            c = model.sphere_clearance(scene, centers, r)
            checked = b["checked"][:, None].expand_as(c)
            big = torch.full_like(c, 1.0)
            preds.append(torch.where(checked, c, big).amin(-1).flatten().cpu().numpy())
            from fetchbench_ms.planning.collision_net import _trilinear

            s = (centers.reshape(1, -1, 3) - model.lo) / model.span
            d = _trilinear(scene["distance"], scene["distance_shape"], s).reshape(c.shape) - r
            cloud.append(torch.where(checked, d, big).amin(-1).flatten().cpu().numpy())
            labels.append(b["label"].flatten().cpu().numpy())
    model.train()
    label, pred = np.concatenate(labels), np.concatenate(preds)
    if false_free_target is not None:
        model.decision_margin = calibrate(pred, label, false_free_target)
    m = model.decision_margin
    return dict(network=confusion(pred < 0, label), decision_margin=m, network_at_margin=confusion(pred < m, label),
                cloud_distance=confusion(np.concatenate(cloud) < 0, label))


def load_weights(path: str, device) -> SceneCollisionNet:
    """A checkpoint's network (``"shipped"``: the package's), in train mode on ``device``."""
    from fetchbench_ms.planning.collision_net import load_collision_net

    load_collision_net.cache_clear()  # (cached per process: a file rewritten in place must be read again)
    model = load_collision_net(None if path == "shipped" else path, "cpu")
    return model.to(device).train()


def judge(args: Args) -> dict:
    """``--judge``: a checkpoint's figures on every query of ``--val``, written to ``--judge-out``."""
    from fetchbench_ms.utils.packed import content_sha256, packed_or_plain

    refuse_test_labels([args.val])
    device = torch.device(args.device)
    val = Tasks(args.val, device)
    model = load_weights(args.judge, device)
    path = packed_or_plain(checkpoint_path() if args.judge == "shipped" else Path(args.judge))
    figures = dict(checkpoint=str(path), checkpoint_sha256=content_sha256(path), val_data_hash=val.hash,
                   val_tasks=val.n, queries_per_task=val.k, validation=evaluate(model, RobotSpheres(device), val, val.k))
    if args.judge_out:
        out = Path(args.judge_out)
        out.parent.mkdir(parents=True, exist_ok=True)
        out.with_suffix(".tmp").write_text(json.dumps(figures, indent=1))
        out.with_suffix(".tmp").replace(out)
    print(json.dumps(figures["validation"]["network"]), flush=True)
    return figures


# -- loop ---------------------------------------------------------------------------------
def main(args: Args) -> None:
    if args.judge:
        judge(args)
        return
    t_start = time.time()
    refuse_test_labels([args.data, args.val])
    run = Path(args.run)
    run.mkdir(parents=True, exist_ok=True)
    log = open(run / "log.txt", "a")

    def say(msg: str) -> None:
        print(msg, flush=True)
        log.write(msg + "\n")
        log.flush()

    device = torch.device(args.device)
    torch.manual_seed(args.seed)
    say(f"# {' '.join(sys.argv)}")
    train, val = Tasks(args.data, device), Tasks(args.val, device)
    overlap = set(train.ids) & set(val.ids)
    if overlap:
        raise SystemExit(f"{len(overlap)} tasks are in both --data and --val, e.g. {sorted(overlap)[:3]}")
    say(f"train: {train.n} tasks x {train.k} queries (hash {train.hash[:16]}), val: {val.n} tasks x {val.k}")
    if args.init_from:
        model = load_weights(args.init_from, device)
        say(f"weights from {args.init_from} (channels {model.config.channels}, hidden {model.config.hidden})")
    else:
        model = SceneCollisionNet(NetConfig(tuple(args.channels), args.hidden)).to(device)
    spheres = RobotSpheres(device)
    opt = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    sched = torch.optim.lr_scheduler.CosineAnnealingLR(opt, args.steps, eta_min=args.lr_final)
    gen = torch.Generator(device="cpu").manual_seed(args.seed)
    step, ckpt = 0, run / "ckpt.pt"
    if ckpt.exists():
        state = torch.load(ckpt, map_location=device, weights_only=False)
        model.load_state_dict(state["model"])
        opt.load_state_dict(state["opt"])
        sched.load_state_dict(state["sched"])
        gen.set_state(state["gen"])
        step = state["step"]
        say(f"resumed at step {step}")

    def save() -> None:
        tmp = run / "ckpt.pt.tmp"
        torch.save(dict(model=model.state_dict(), opt=opt.state_dict(), sched=sched.state_dict(), gen=gen.get_state(),
                        step=step, args=dataclasses.asdict(args)), tmp)
        tmp.replace(ckpt)

    amp = args.amp and device.type == "cuda"
    t_log, n_seen = time.time(), 0
    while step < args.steps:
        if args.time_limit > 0 and time.time() - t_start > args.time_limit:
            save()
            say(f"time limit: stopped at step {step} (re-run the same command to resume)")
            return
        tasks = torch.randint(train.n, (args.scenes,), generator=gen).to(device)
        idx = torch.randint(train.k, (args.scenes, args.queries), generator=gen).to(device)
        b = train.batch(tasks, idx)
        with torch.autocast(device.type, dtype=torch.bfloat16, enabled=amp):
            pred = forward(model, spheres, b)
        loss, parts = loss_fn(pred.float(), b, args)
        opt.zero_grad(set_to_none=True)
        loss.backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), 1.0)
        opt.step()
        sched.step()
        step += 1
        n_seen += args.scenes * args.queries
        if step % args.log_every == 0:
            dt = time.time() - t_log
            say(f"step {step} loss {float(loss):.4f} reg {parts['reg']:.4f} cls {parts['cls']:.4f} "
                f"lr {sched.get_last_lr()[0]:.2e} {n_seen / dt:.0f} queries/s")
            t_log, n_seen = time.time(), 0
        if step % args.ckpt_every == 0:
            save()
        if step % args.val_every == 0 or step == args.steps:
            figures = evaluate(model, spheres, val, args.val_queries)
            say(f"val step {step}: {json.dumps(figures)}")
    save()
    figures = evaluate(model, spheres, val, val.k, args.false_free_target)
    say(f"final val (all {val.k} queries of {val.n} tasks): {json.dumps(figures)}")
    if args.export:
        out = Path(args.export_path) if args.export_path else checkpoint_path()
        save_checkpoint(model, out)
        meta = dict(command="python " + " ".join(sys.argv), train_data_hash=train.hash, train_tasks=train.n,
                    queries_per_task=train.k, val_data_hash=val.hash, val_tasks=val.n, steps=step,
                    args=dataclasses.asdict(args), validation=figures,
                    size_bytes=out.stat().st_size)
        tmp = out.with_suffix(".json.tmp")
        tmp.write_text(json.dumps(meta, indent=1, default=str))
        tmp.replace(out.with_suffix(".json"))
        say(f"exported {out} ({out.stat().st_size / 1e6:.2f} MB) and {out.with_suffix('.json')}")
        if args.export_dir:
            import shutil

            dest = Path(args.export_dir)
            dest.mkdir(parents=True, exist_ok=True)
            for f in (out, out.with_suffix(".json"), run / "log.txt"):
                shutil.copy(f, dest / f.name)


if __name__ == "__main__":
    import tyro

    main(tyro.cli(Args))

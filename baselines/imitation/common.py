"""What the imitation trainers share: the frames on the device, batches, the run folder
(log, checkpoint, resume, time limit), validation (held-out demos' loss; success on `val`
suite tasks through `fetchbench eval`), the export (under the run folder: making it the
package's checkpoint is scripts/maint/ship_imitation.py's step) and of the
``--save-every`` candidates that ``scripts/imitation/select_checkpoint.py`` chooses from on val tasks.
Training files of test tasks are refused before anything is written (``tasks.splits``).

The trainers (``train_mlp.py``, ``train_transformer.py``, ``train_diffusion.py``, ``train_act.py``) hold their
arguments, their model and their loss; read one of them first.
"""
from __future__ import annotations

import dataclasses
import hashlib
import json
import math
import os
import shlex
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Optional

import numpy as np
import torch

from fetchbench_ms.envs.pointcloud import COMPACT_OBS_MODE
from fetchbench_ms.method_spec import POLICY_KINDS
from fetchbench_ms.policies.agent import load_model, save_checkpoint
from fetchbench_ms.policies.data import POLICY_SIZES, POLICY_STAGES, load_training_files
from fetchbench_ms.policies.networks import EncoderConfig, config_to_dict
from fetchbench_ms.tasks.splits import cli_guard, refuse_test_task_ids
from fetchbench_ms.utils.io import atomic_write_text, sha256_bytes, sha256_file
from fetchbench_ms.utils.packed import content_sha256, packed_or_plain

EVAL_METHOD = {kind: f"e2e-{kind}" for kind in POLICY_KINDS}  # the val-success method of each kind
EVAL_SUITE = "val"  # success is measured on val tasks, never test
EARLY_LOG_STEPS = (1, 2, 5, 10, 20, 50)  # logged before the first --log-every: the rate and ETA show at once


@dataclass
class TrainArgs:
    data: str = "data/imit"  # folder of *.imit.h5 training files (scripts/imitation/convert_demos_for_imitation.py)
    run: str = ""  # run folder: log, checkpoint (re-running resumes); default runs/imit/<kind>
    device: str = "cuda" if torch.cuda.is_available() else "cpu"
    seed: int = 0
    steps: int = 30000
    batch_size: int = 256
    lr: float = 3e-4
    lr_final: float = 1e-5  # cosine decay to this
    warmup: int = 500
    weight_decay: float = 1e-4
    grad_clip: float = 1.0
    scene_points: int = POLICY_SIZES["scene"]
    target_points: int = POLICY_SIZES["target"]
    robot_points: int = POLICY_SIZES["robot"]
    termination_weight: float = 1.0
    termination_pos_weight: float = 10.0  # few frames end a stage
    termination_window: int = 3  # the last k frames of a stage are labelled terminal
    point_jitter: float = 0.002  # m, Gaussian noise on the training points
    val_fraction: float = 0.05  # demos held out (by task) for the validation loss
    val_every: int = 1000  # steps between validation losses
    eval_every: int = 10000  # steps between success evaluations on val tasks (and at the end); 0: never
    eval_tasks: int = 32  # the first N tasks of the val suite
    eval_workers: int = min(16, os.cpu_count() or 1)  # processes of the val-success evaluation
    time_limit: float = 0.0  # s; > 0: checkpoint and stop after this long (re-run to resume)
    until_step: int = 0  # > 0: checkpoint and stop at this step (re-run to resume; the LR schedule spans --steps)
    new_data: bool = False
    """Resume the run's checkpoint on other data: the next shard of a dataset converted and
    trained in several runs (scripts/imitation/convert_demos_for_imitation.py --start). Each data hash and
    the step it began at are recorded (checkpoint, export JSON)."""
    init_from: str = ""
    """Start a new run folder from an exported checkpoint (assets/checkpoints/imit_<kind>.pt or a
    hold's export): its weights, step and data history go on; the optimiser starts afresh (an
    export has no Adam moments) and the learning rate warms up again over --warmup steps. What
    carries a run from one session to the next when its full checkpoint (~85 MB with the
    optimiser state, three trainers) could not be kept: an export is the fp16 weights alone."""
    log_every: int = 100
    """steps between progress lines (the first steps are logged too: the rate and ETA show at once)"""
    ckpt_every: int = 1000
    """steps between the run's full checkpoints (<run>/checkpoint.pt; re-running resumes from it)"""
    save_every: int = 0
    """> 0: every this many steps, and at the end of the schedule, export a candidate checkpoint
    (<run>/candidates/step_NNNNNNN.pt + .json, as --export writes): what
    scripts/imitation/select_checkpoint.py chooses from on val tasks"""
    export: bool = False
    """When done, export the fp16 checkpoint and its JSON (evaluate it with `fetchbench eval
    --policy-checkpoint`; scripts/maint/ship_imitation.py makes it the package's own)"""
    export_path: str = ""  # default <run>/export/imit_<kind>.pt; never the package's checkpoints
    point_dims: tuple[int, ...] = (64, 128, 256)  # the shared PointNet's layer widths

    def sizes(self) -> dict:
        return {"scene": self.scene_points, "target": self.target_points, "robot": self.robot_points}

    def encoder(self) -> EncoderConfig:
        return EncoderConfig(sizes=self.sizes(), point_dims=tuple(self.point_dims), point_out=self.point_dims[-1])


# ----------------------------------------------------------------------------- data
def data_hash(files: list[str]) -> str:
    """The hash of the training files a run loaded: of their names and sha256s. (Not the
    folder's manifest: a conversion still writing its shard, read by the trainers of the same
    hold, adds chunks between the loading and a look at the manifest.) The chunks' sha256s are
    the ones in the converter's manifest.json."""
    lines = "".join(f"{Path(f).name} {sha256_file(f)}\n" for f in sorted(files, key=lambda f: Path(f).name))
    return sha256_bytes(lines.encode())


def training_task_ids(data: str) -> list:
    """The task ids of the demos in the training files of ``data`` (read from the files'
    attributes only: a cheap look before any work)."""
    import h5py

    path = Path(data)
    files = sorted(path.glob("*.imit.h5")) if path.is_dir() else [path] if path.is_file() else []
    ids = []
    for f in files:
        with h5py.File(f, "r") as h:
            ids += [e.get("task_id") for e in json.loads(h.attrs.get("episodes", "[]"))]
    return ids


def run_dir(args: TrainArgs, kind: str) -> Path:
    return Path(args.run or f"runs/imit/{kind}")


def export_path(args: TrainArgs, kind: str) -> Path:
    """Where ``--export`` writes: ``--export-path``, by default ``<run>/export/imit_<kind>.pt``."""
    return Path(args.export_path) if args.export_path else run_dir(args, kind) / "export" / f"imit_{kind}.pt"


def check_export_path(args: TrainArgs, kind: str) -> None:
    """A training run never writes the package's checkpoints (``fetchbench eval`` would load
    it in place of the shipped one): an ``--export-path`` in that folder is one line and exit 2."""
    from fetchbench_ms.policies.deploy import default_checkpoint

    shipped = default_checkpoint(kind).parent
    if args.export and export_path(args, kind).resolve().parent == shipped.resolve():
        print(f"error: --export-path {args.export_path} is in the package's checkpoint folder {shipped}; export under "
              f"the run (the default, {export_path(dataclasses.replace(args, export_path=''), kind)}) and evaluate it "
              "with `fetchbench eval --policy-checkpoint PATH`; scripts/maint/ship_imitation.py --run RUN makes "
              "it the shipped one", file=sys.stderr, flush=True)
        raise SystemExit(2)


def progress(done: int, seconds: float, left: int, limit_left: Optional[float] = None) -> str:
    """``N steps/s, ETA ...``: the rate of this call's ``done`` steps in ``seconds``, and when
    the ``left`` steps would be done; a ``--time-limit`` (``limit_left`` s) that comes first is named."""
    rate = done / max(seconds, 1e-9)
    eta = left / max(rate, 1e-9)
    text = f"{rate:.2f} steps/s, ETA {_duration(eta)}"
    if limit_left is not None and eta > limit_left:
        text += f"; --time-limit stops this call in {_duration(max(limit_left, 0.0))}"
    return text


def _duration(seconds: float) -> str:
    seconds = int(round(seconds))
    return f"{seconds // 3600}h{seconds % 3600 // 60:02d}m" if seconds >= 3600 else f"{seconds // 60}m{seconds % 60:02d}s"


def candidate_path(run: Path, step: int) -> Path:
    """Where ``--save-every`` exports the candidate checkpoint of ``step``."""
    return Path(run) / "candidates" / f"step_{step:07d}.pt"


def _is_val_task(task_id: str, fraction: float) -> bool:
    return int(hashlib.sha256(str(task_id).encode()).hexdigest()[:8], 16) / 2**32 < fraction


class Frames:
    """The training frames as device tensors, with the indices a batch needs."""

    def __init__(self, raw: dict, device: str, args: TrainArgs):
        self.device = torch.device(device)
        t = lambda x: torch.from_numpy(np.ascontiguousarray(x)).to(self.device)  # noqa: E731
        self.points, self.point_label = t(raw["points"]), t(raw["point_label"])
        self.qpos, self.tcp, self.action = t(raw["qpos"]), t(raw["tcp"]), t(raw["action"])
        self.stage = t(raw["stage"].astype(np.int64))
        F_ = len(raw["qpos"])
        # Segments: runs of one stage within one demo; a frame's history and action chunk
        # stay inside its segment (padded by its first frame / by holding).
        episode = np.repeat(np.arange(len(raw["episode_length"])), raw["episode_length"])
        new = np.r_[True, (raw["stage"][1:] != raw["stage"][:-1]) | (episode[1:] != episode[:-1])]
        seg_id = np.cumsum(new) - 1
        starts = np.flatnonzero(new)
        ends = np.r_[starts[1:], F_]  # exclusive
        self.seg_start = t(starts[seg_id])
        self.seg_end = t(ends[seg_id])
        # Terminal: the stage's last `termination_window` frames, for segments that end a stage.
        stage_ends = np.zeros(len(starts), bool)
        stage_ends[seg_id[raw["stage_end"]]] = True
        to_end = ends[seg_id] - np.arange(F_)
        self.terminal = t(stage_ends[seg_id] & (to_end <= args.termination_window))
        policy_frame = np.isin(raw["stage"], POLICY_STAGES)
        tasks = [e.get("task_id") or f"{e['source']}#{e['episode_id']}" for e in raw["episodes"]]
        val_task = np.array([_is_val_task(task, args.val_fraction) for task in tasks])
        if val_task.all() or (not val_task.any() and len(set(tasks)) > 1):
            # A small dataset: hold out (only) the last task's demos.
            val_task = np.array([task == tasks[-1] for task in tasks])
        frame_val = val_task[episode]
        self.train_index = t(np.flatnonzero(policy_frame & ~frame_val))
        self.val_index = t(np.flatnonzero(policy_frame & frame_val))
        self.demos = {"train": int((~val_task).sum()), "val": int(val_task.sum())}
        # Converted steps a frame stands for (--frame-stride): what a deployment's
        # --policy-stride should be; the checkpoint and the export record it.
        self.frame_stride = int(raw.get("frame_stride", 1))
        # The env obs mode the points were made with: the policy reads that mode at deployment.
        self.obs_mode = raw.get("obs_mode") or COMPACT_OBS_MODE
        # Where the actions were labelled (policies.data: the replay's states or the expert's own).
        self.labels = raw.get("labels") or "replay"

    def observation(self, index: torch.Tensor, history: int = 1, jitter: float = 0.0,
                    generator: Optional[torch.Generator] = None) -> dict:
        """The model input of frames ``index`` [B]: [B, ...] (history 1) or [B, H, ...] (oldest first)."""
        if history == 1:
            rows = index
        else:
            offsets = torch.arange(1 - history, 1, device=self.device)
            rows = torch.maximum(index[:, None] + offsets, self.seg_start[index][:, None])
        points = self.points[rows].float()
        if jitter:
            points = points + jitter * torch.randn(points.shape, device=self.device, generator=generator)
        return {"points": points, "point_label": self.point_label[rows], "qpos": self.qpos[rows],
                "tcp": self.tcp[rows], "stage": self.stage[rows]}

    def action_chunk(self, index: torch.Tensor, horizon: int, with_mask: bool = False):
        """[B, horizon, 7]: the actions from each frame on; past its segment's end, zeros (the arm holds).
        ``with_mask``: also [B, horizon] bool, True where the action is inside the segment."""
        rows = index[:, None] + torch.arange(horizon, device=self.device)
        inside = rows < self.seg_end[index][:, None]
        chunk = self.action[rows.clamp(max=len(self.action) - 1)] * inside[..., None]
        return (chunk, inside) if with_mask else chunk


def load_frames(args: TrainArgs, log) -> tuple[Frames, str]:
    raw = load_training_files(args.data, sizes=args.sizes())
    frames = Frames(raw, args.device, args)
    log(f"data {args.data}: {len(raw['files'])} files, {len(raw['episodes'])} demos "
        f"({frames.demos['train']} train, {frames.demos['val']} val), "
        f"{len(raw['qpos'])} frames ({len(frames.train_index)} train / {len(frames.val_index)} val policy frames), "
        f"{raw['points'].nbytes / 1e9:.2f} GB of points; frames every {frames.frame_stride} converted steps")
    if len(frames.train_index) == 0:
        raise ValueError(f"no training frame in {args.data}")
    return frames, data_hash(raw["files"])


# ----------------------------------------------------------------------------- the loop
def lr_at(step: int, args: TrainArgs, restart: int = 0) -> float:
    """Linear warm-up, then cosine decay to ``lr_final`` at ``--steps``; ``restart``: the step a
    fresh optimiser took over (``--init-from``), from which the rate warms up again."""
    if step < args.warmup:
        return args.lr * (step + 1) / args.warmup
    progress = (step - args.warmup) / max(1, args.steps - args.warmup)
    rate = args.lr_final + 0.5 * (args.lr - args.lr_final) * (1 + math.cos(math.pi * min(1.0, progress)))
    if restart and step - restart < args.warmup:
        rate *= (step - restart + 1) / args.warmup
    return rate


def init_from_export(path: str, model: torch.nn.Module, frames: Frames, dhash: str, args: TrainArgs) -> dict:
    """Load an exported checkpoint's weights into ``model`` (built from ``args``: the export's
    network must be the same) for ``--init-from``; returns the run's starting history."""
    path = packed_or_plain(path)  # a shipped checkpoint is read from its packed copy
    exported, meta = load_model(path)
    if exported.kind != model.kind:
        raise ValueError(f"--init-from {path} is a {exported.kind} checkpoint, this trainer trains {model.kind}")
    have, want = config_to_dict(exported.cfg), config_to_dict(model.cfg)
    if have != want:
        differ = sorted(k for k in {*have, *want} if have.get(k) != want.get(k))
        raise ValueError(f"--init-from {path}: its network differs from these arguments' in {', '.join(differ)} "
                         f"({', '.join(f'{k}: {have.get(k)} vs {want.get(k)}' for k in differ)})")
    stride = int(meta.get("frame_stride", 1))
    if stride != frames.frame_stride:
        raise ValueError(f"--init-from {path} was trained on frames every {stride} converted steps, {args.data} holds "
                         f"frames every {frames.frame_stride} (--frame-stride): a run learns from one frame stride")
    if meta.get("data_sha256") != dhash and not args.new_data:
        raise ValueError(f"--init-from {path} was trained on other data ({str(meta.get('data_sha256'))[:12]} vs "
                         f"{dhash[:12]}): add --new-data to go on with this data (the next shard)")
    model.load_state_dict(exported.state_dict())
    step = int(meta["step"])
    data = [dict(d) for d in meta.get("data_history") or [{"data_sha256": meta["data_sha256"], "from_step": 0}]]
    if meta["data_sha256"] != dhash:
        data.append({"data_sha256": dhash, "from_step": step, "labels": frames.labels})
    return {"step": step, "val_loss": [], "val_success": [], "data": data,
            "init_from": {"path": str(path), "sha256": content_sha256(path), "step": step}}


def train(args: TrainArgs, kind: str, make_model: Callable[[], torch.nn.Module],
          batch_loss: Callable[[torch.nn.Module, Frames, torch.Tensor, torch.Generator], dict]) -> dict:
    """Train ``make_model()`` (built after seeding) with ``batch_loss(model, frames, index,
    generator) -> {"loss": ..., ...}``; returns the model and the last figures. Resumes from
    ``<run>/checkpoint.pt``."""
    # Demos of test tasks are never learnt from (refused before anything is written; the
    # success figures below are measured on EVAL_SUITE, val).
    cli_guard(refuse_test_task_ids, training_task_ids(args.data), f"{kind} imitation training")
    check_export_path(args, kind)
    run = run_dir(args, kind)
    run.mkdir(parents=True, exist_ok=True)
    log_file = open(run / "log.txt", "a")
    command = " ".join(shlex.quote(a) for a in [sys.executable.rsplit("/", 1)[-1], *sys.argv])

    def log(message: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {message}"
        print(line, flush=True)
        log_file.write(line + "\n")
        log_file.flush()

    t_start = time.perf_counter()
    frames, dhash = load_frames(args, log)
    # TF32 matmuls: the PointNet's per-point layers are most of a step, and TF32's 10-bit
    # mantissa is far below the noise of behaviour cloning's targets.
    torch.backends.cuda.matmul.allow_tf32 = True
    torch.backends.cudnn.allow_tf32 = True
    torch.manual_seed(args.seed)
    model = make_model().to(args.device)
    model.cfg.encoder.obs_mode = frames.obs_mode  # (saved with the config: the deployment's obs mode)
    n_params = sum(p.numel() for p in model.parameters())
    optimizer = torch.optim.AdamW(model.parameters(), lr=args.lr, weight_decay=args.weight_decay)
    generator = torch.Generator(device=args.device).manual_seed(args.seed)
    step, history, ckpt = 0, {"val_loss": [], "val_success": []}, run / "checkpoint.pt"
    if ckpt.is_file():
        saved = torch.load(ckpt, map_location=args.device, weights_only=False)
        saved_mode = saved.get("obs_mode", COMPACT_OBS_MODE)
        if saved_mode != frames.obs_mode:
            raise ValueError(f"{ckpt} was trained on {saved_mode} frames, {args.data} holds {frames.obs_mode} "
                             "frames: a run learns from one obs mode; use another --run")
        saved_stride = saved.get("frame_stride", 1)  # (checkpoints before the frame stride: every step)
        if saved_stride != frames.frame_stride:
            raise ValueError(f"{ckpt} was trained on frames every {saved_stride} converted steps, {args.data} holds "
                             f"frames every {frames.frame_stride} (--frame-stride): a run learns from one frame "
                             "stride; use another --run")
        if saved["data_sha256"] != dhash and not args.new_data:
            raise ValueError(f"{ckpt} was trained on other data ({saved['data_sha256'][:12]} vs {dhash[:12]}): "
                             "use another --run, or --new-data to go on with this data (the next shard)")
        model.load_state_dict(saved["model"])
        optimizer.load_state_dict(saved["optimizer"])
        generator.set_state(saved["generator"].cpu())  # (map_location moved it)
        step, history = saved["step"], saved["history"]
        history.setdefault("data", [{"data_sha256": saved["data_sha256"], "from_step": 0}])
        if saved["data_sha256"] != dhash:
            history["data"].append({"data_sha256": dhash, "from_step": step, "labels": frames.labels})
            log(f"resumed at step {step} on new data {dhash[:12]} (was {saved['data_sha256'][:12]})")
        else:
            log(f"resumed at step {step}")
    elif args.init_from:
        history = init_from_export(args.init_from, model, frames, dhash, args)
        step = history.pop("step")
        # Other batches than the run's first steps drew (the generator's state is not exported).
        generator.manual_seed(args.seed + step)
        log(f"{kind}: {n_params / 1e6:.2f} M parameters; from {args.init_from} at step {step} "
            f"(sha256 {history['init_from']['sha256'][:12]}; a fresh optimiser, warming up over {args.warmup} steps); "
            f"{command}")
    else:
        history["data"] = [{"data_sha256": dhash, "from_step": 0, "labels": frames.labels}]
        log(f"{kind}: {n_params / 1e6:.2f} M parameters; {command}")
    restart = history.get("init_from", {}).get("step", 0)

    def save() -> None:
        payload = {"model": model.state_dict(), "optimizer": optimizer.state_dict(), "generator": generator.get_state(),
                   "step": step, "history": history, "args": dataclasses.asdict(args), "data_sha256": dhash,
                   "frame_stride": frames.frame_stride, "obs_mode": frames.obs_mode}
        tmp = ckpt.with_name(ckpt.name + ".tmp")
        torch.save(payload, tmp)
        tmp.replace(ckpt)

    def val_loss() -> dict:
        if len(frames.val_index) == 0:
            return {}
        model.eval()
        sums: dict = {}
        val_gen = torch.Generator(device=args.device).manual_seed(1234)  # the same noise every time
        with torch.no_grad():
            for chunk in frames.val_index.split(args.batch_size):
                out = batch_loss(model, frames, chunk, val_gen)
                for k, v in out.items():
                    sums[k] = sums.get(k, 0.0) + float(v) * len(chunk)
        model.train()
        return {k: v / len(frames.val_index) for k, v in sums.items()}

    def val_success() -> dict:
        ckpt_path = run / "eval" / f"step_{step}.pt"
        ckpt_path.parent.mkdir(parents=True, exist_ok=True)
        # The policy acts at its data's time scale: an observation (and an arm action) every
        # frame_stride control steps, a diffusion chunk's actions frame_stride steps each.
        save_checkpoint(ckpt_path, model, {"step": step, "frame_stride": frames.frame_stride})
        from fetchbench_ms.evaluation.metrics import summarize
        from fetchbench_ms.evaluation.runner import evaluate

        records = evaluate(EVAL_METHOD[kind], run / "eval" / f"step_{step}", suite=EVAL_SUITE,
                           tasks=f"0:{args.eval_tasks}", workers=args.eval_workers,
                           policy_checkpoint=str(ckpt_path), progress=False, policy_stride=frames.frame_stride)
        summary = summarize(records)
        return {"step": step, "tasks": len(records), "success_rate": summary["all"]["success_rate"],
                "errors": summary["all"]["errors"], "policy_stride": frames.frame_stride}

    def evaluate_now() -> None:
        save()  # an evaluation takes minutes: do not lose the steps before it (its results resume too)
        log(f"val success step {step}: running {EVAL_METHOD[kind]} on {args.eval_tasks} val tasks, "
            f"{args.eval_workers} workers (--eval-tasks, --eval-workers; --eval-every 0: none)")
        result = val_success()
        history["val_success"].append(result)
        save()
        log(f"val success step {step}: {result['success_rate']:.3f} on {result['tasks']} val tasks "
            f"({result['errors']} errors)")

    model.train()
    last: dict = {}
    stopped, step_at_start, t_loop = False, step, time.perf_counter()
    target = min(args.steps, args.until_step) if args.until_step else args.steps
    while step < args.steps:
        if args.until_step and step >= args.until_step:
            save()
            log(f"until step {args.until_step}: checkpoint at step {step}; resume with a later --until-step (or none)")
            stopped = True
            break
        for group in optimizer.param_groups:
            group["lr"] = lr_at(step, args, restart)
        pick = torch.randint(len(frames.train_index), (args.batch_size,), device=args.device, generator=generator)
        out = batch_loss(model, frames, frames.train_index[pick], generator)
        optimizer.zero_grad(set_to_none=True)
        out["loss"].backward()
        torch.nn.utils.clip_grad_norm_(model.parameters(), args.grad_clip)
        optimizer.step()
        step += 1
        if step % args.log_every == 0 or step - step_at_start in EARLY_LOG_STEPS:
            limit_left = args.time_limit - (time.perf_counter() - t_start) if args.time_limit else None
            last = {k: round(float(v.detach()), 5) for k, v in out.items()}
            log(f"step {step}/{args.steps} lr {lr_at(step, args, restart):.2e} "
                + " ".join(f"{k} {v:.4f}" for k, v in last.items())
                + f" ({progress(step - step_at_start, time.perf_counter() - t_loop, target - step, limit_left)})")
        if step % args.val_every == 0 or step == args.steps:
            figures = val_loss()
            if figures:
                history["val_loss"].append({"step": step, **{k: round(v, 5) for k, v in figures.items()}})
                log(f"val step {step} " + " ".join(f"{k} {v:.4f}" for k, v in figures.items()))
        if args.eval_every and args.eval_tasks and step % args.eval_every == 0 and step < args.steps:
            evaluate_now()
        if args.save_every and (step % args.save_every == 0 or step == args.steps):
            export(model, kind, args, command, dhash, frames.frame_stride, step, history, last, log,
                   path=candidate_path(run, step))
        if step % args.ckpt_every == 0:
            save()
        if args.time_limit and time.perf_counter() - t_start > args.time_limit and step < args.steps:
            save()
            log(f"time limit: checkpoint at step {step}; run the same command again to resume")
            stopped = True
            break
    if not stopped:
        save()
        # The final evaluation, also when a call was cut off during it (re-running finishes it).
        if args.eval_every and args.eval_tasks and not any(r["step"] == step for r in history["val_success"]):
            evaluate_now()
        log(f"done: {step} steps")
    if args.export:
        # Also a run stopped by --time-limit / --until-step exports (one shard of a longer
        # run ships what it has); the JSON says whether the schedule was finished.
        export(model, kind, args, command, dhash, frames.frame_stride, step, history, last, log)
    return {"model": model, "step": step, "last": last, "history": history, "stopped": stopped}


def export(model, kind: str, args: TrainArgs, command: str, dhash: str, frame_stride: int, step: int, history: dict,
           last: dict, log, path: Optional[Path] = None) -> Path:
    """``<run>/export/imit_<kind>.pt`` (fp16; or ``--export-path``, or ``path``: a
    ``--save-every`` candidate) and ``.json`` beside it: the command, the data hash and frame
    stride, the steps and the validation figures."""
    path = Path(path or export_path(args, kind))
    path.parent.mkdir(parents=True, exist_ok=True)
    meta = {"kind": kind, "step": step, "schedule_complete": step >= args.steps, "data_sha256": dhash,
            "frame_stride": frame_stride, "obs_mode": model.cfg.encoder.obs_mode,
            "data_history": history.get("data", []), "init_from": history.get("init_from"), "command": command,
            "validation": {"loss": history["val_loss"][-1] if history["val_loss"] else None,
                           "success": history["val_success"]}}
    size = save_checkpoint(path, model, meta)
    atomic_write_text(path.with_suffix(".json"), json.dumps(
        {**meta, "args": dataclasses.asdict(args), "last_train_loss": last, "checkpoint_bytes": size,
         "validation_loss_history": history["val_loss"]}, indent=1))
    log(f"exported {path} ({size / 1e6:.2f} MB)")
    return path

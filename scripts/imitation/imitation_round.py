"""One round of the imitation dataset that grows round by round, as one command.

    # a 2-GPU node (32 cores): ~20 minutes
    python scripts/imitation/imitation_round.py --work out/rounds --tasks 600 --per-task 3 --procs 32 --gpus 0,1 --ship
    # one GPU and 16 cores, one kind: ~11 minutes
    python scripts/imitation/imitation_round.py --work out/rounds --tasks 500 --procs 16 --gpus 0 --kinds mlp --steps mlp=5000 --ship
    # where the rounds stand: every round's data, steps and val figures, and the plateau check
    python scripts/imitation/imitation_round.py --status
    # the validation curve (val success against demos seen, per method) from the record
    python scripts/imitation/imitation_round.py --plot docs/img/imitation-rounds.png

A round takes the next ``--tasks`` tasks of the ``train`` suite after the last round's and:

1. **data**: the expert on them (up to ``--per-task`` trajectories a task) and their frames in
   ``composed_pointcloud`` at frame stride 3 at the demos' own states, no replay (``--labels
   expert-states``; ``scripts/imitation/build_imitation_data.py``);
2. **training**: each policy kind (``--kinds``) for its ``--steps`` on this round's frames,
   from the shipped checkpoint of its kind when that one reads ``composed_pointcloud``
   (``--init-from``, ``--new-data``: the weights go on, the data is new), else from scratch;
   the kinds share the GPUs in turn (``scripts/imitation/train_imitation_gpus.py``);
3. **val**: each candidate end to end (``e2e-<kind>``) and as the hybrid
   (``cgn-imit-<kind>``, the paper's pipeline) on ``--val-tasks`` (val 0:100) at policy stride 3,
   the runs at once with the ``--procs`` workers shared among them (``RUN/val/<method>/eval.log``);
4. **choice**: a candidate replaces the shipped checkpoint of its kind when its val successes,
   summed over the methods the shipped one has val figures of on the same tasks, exceed the
   shipped one's (a tie keeps the shipped one); with ``--ship`` the winners are written to
   ``assets/checkpoints/`` with their JSON (the command, the data manifest, the val figures)
   by ``scripts/maint/ship_imitation.py``;
5. **record**: the round is appended to ``--record``/rounds.json: its tasks, demos, frames,
   the data's hash, the expert's rate, every kind's steps, init, val figures and whether it
   shipped, and the machine it ran on. Each round trains on its own new data from the previous
   weights (the data itself is not kept: a round's frames are ~1.5 GB); ``demos_seen`` of a kind counts the demos of
   every round its shipped lineage trained on.

Every step resumes in ``--work``/round_NN (finished demos, chunks, trainer checkpoints and
eval records are kept), so the same command continues a round that stopped; a round already
in the record is not redone. Budgets are counts (tasks, steps, val tasks); ``--time-limit``
stops a trainer early only as a safety net (its steps are recorded). The test split never
trains or chooses: the data is from ``train``, the choice from ``val``.
"""
from __future__ import annotations

import argparse
import json
import os
import shlex
import subprocess
import sys
import time
from pathlib import Path

from fetchbench_ms.utils.rounds import answer_report, next_tasks, no_gain_in_two, parse_slice, round_log

ROOT = Path(__file__).resolve().parents[2]
RECORD = ROOT / "results/training/imitation-rounds"
KINDS = ("act", "transformer", "mlp", "diffusion")  # (the order the GPUs are handed out in)
#: Steps a round trains each kind for: ~4 minutes a kind with a GPU each (measured rates: act 28,
#: transformer 34, mlp 70, diffusion 25 steps a second on an H200), about twice that two a GPU.
DEFAULT_STEPS = {"act": 6000, "transformer": 6000, "mlp": 12000, "diffusion": 5000}
OBS_MODE = "composed_pointcloud"
FRAME_STRIDE = 3
#: The frames are the demos' own recorded states, no replay (policies.data.expert_state_episodes).
LABELS = "expert-states"
VAL_TASKS = "0:100"
#: The hybrids' approach planner counts in val runs: every round's val figures, the shipped
#: checkpoints' among them, were made with these, so a candidate is judged like its rival.
HYBRID_TRAJOPT_COUNTS = "16x80x3"
MIN_VAL_TASKS = 100


def methods(kind: str) -> tuple[str, str]:
    """The val methods of a kind: end to end, and the hybrid."""
    return f"e2e-{kind}", f"cgn-imit-{kind}"


def load_record(record: Path) -> dict:
    path = record / "rounds.json"
    if path.is_file():
        return json.loads(path.read_text())
    return {"obs_mode": OBS_MODE, "frame_stride": FRAME_STRIDE, "labels": LABELS, "suite": "train", "val": {"suite": "val"},
            "rounds": []}


def parse_steps(text: str | None) -> dict:
    steps = dict(DEFAULT_STEPS)
    for item in filter(None, (text or "").split(",")):
        kind, _, value = item.partition("=")
        if kind not in KINDS or not value.isdigit() or int(value) < 1:
            raise SystemExit(f"--steps {text!r}: KIND=N pairs, N >= 1, KIND of {', '.join(KINDS)}")
        steps[kind] = int(value)
    return steps


def run(command: list[str], log) -> None:
    log(f"$ {shlex.join(command)}")
    code = subprocess.call(command, cwd=ROOT)
    if code != 0:
        raise SystemExit(f"stopped: exit {code} from {shlex.join(command[:3])} ...; run the same command to resume")


def shipped(kind: str) -> tuple[Path, dict]:
    """The shipped checkpoint of a kind and its JSON."""
    from fetchbench_ms.policies.deploy import default_checkpoint
    from fetchbench_ms.utils.packed import packed_or_plain

    path = packed_or_plain(default_checkpoint(kind))
    side = default_checkpoint(kind).with_suffix(".json")
    if not path.is_file() or not side.is_file():
        # The package ships every kind: a missing one is a broken tree, and treating it as
        # "nothing shipped" would ship any candidate without comparing it.
        raise SystemExit(f"{path} or {side.name} is missing: the round compares each kind's candidate with its "
                         f"shipped checkpoint (restore assets/checkpoints/imit_{kind}.*)")
    return path, json.loads(side.read_text())


def machine(gpus: list[str] | None) -> str:
    """The machine a round ran on, for its record: cores, and the GPUs it used."""
    cores = f"{os.cpu_count()} cores"
    if not gpus:
        return cores
    import torch

    names = sorted({torch.cuda.get_device_name(int(g)) for g in gpus})
    return f"{cores}, {len(gpus)} GPU{'s' if len(gpus) > 1 else ''} ({', '.join(names)})"


def export_complete(meta_path: Path, steps: int) -> bool:
    """Whether a round's export of a kind exists with all its ``steps``."""
    return meta_path.is_file() and int(json.loads(meta_path.read_text()).get("step", -1)) >= steps


def val_successes(meta: dict, method: str, tasks: tuple[int, int]) -> int | None:
    """A shipped checkpoint's val successes of ``method`` on exactly ``tasks`` (None: no such run)."""
    for v in meta.get("validation_success", []):
        first, last = v.get("first_task", ""), v.get("last_task", "")
        if v["method"] == method and first == f"val/{tasks[0]:04d}" and last == f"val/{tasks[1] - 1:04d}":
            return int(v["successes"])
    return None


def eval_successes(folder: Path) -> tuple[int, int]:
    records = [json.loads(line) for line in (folder / "results.jsonl").read_text().splitlines() if line.strip()]
    return sum(bool(r.get("success")) for r in records), len(records)


def choose(candidate: dict, shipped_meta: dict, tasks: tuple[int, int]) -> dict:
    """The choice rule (module docstring): summed over the methods the shipped one has val runs of."""
    compared = {m: val_successes(shipped_meta, m, tasks) for m in candidate}
    compared = {m: n for m, n in compared.items() if n is not None}
    if not compared:
        return {"ships": True, "why": "no shipped checkpoint with val figures on these tasks", "compared": {}}
    new, old = sum(candidate[m] for m in compared), sum(compared.values())
    return {"ships": new > old, "compared": {m: [candidate[m], n] for m, n in compared.items()},
            "why": f"{new} val successes against the shipped one's {old} ({', '.join(compared)})"}


def plateau(record: dict) -> bool:
    """No round's best val success (of any method) above the best before it, two rounds running."""
    return no_gain_in_two([max((v["success_rate"] for k in r["kinds"].values() for v in k["val"].values()),
                               default=0.0) for r in record["rounds"]])


def status(record: dict) -> str:
    lines = [f"{len(record['rounds'])} rounds, obs mode {record['obs_mode']}, frame stride {record['frame_stride']}"]
    for r in record["rounds"]:
        lines.append(f"round {r['round']}: train tasks {r['tasks'][0]}:{r['tasks'][1]}, {r['demos']} demos, "
                     f"{r['frames']} frames")
        for kind, k in r["kinds"].items():
            val = ", ".join(f"{m} {v['successes']}/{v['tasks']}" for m, v in k["val"].items())
            lines.append(f"  {kind}: steps {k['steps'][0]}->{k['steps'][1]}, {k['demos_seen']} demos seen; {val}; "
                         f"{'shipped' if k['shipped'] else 'not shipped'} ({k['choice']['why']})")
    lines.append("plateau: val success has not improved for two rounds" if plateau(record)
                 else "no plateau yet: another round can improve val")
    return "\n".join(lines)


#: The records behind docs/imitation-rounds.md's cost figures (``--costs`` prints its block).
COST_RECORDS = {"cpu2": "results/training/bench-policy-obs-cpu2.json",
                "node": "results/training/bench-policy-obs-2xh200.json",
                "node32": "results/training/bench-policy-obs-2xh200-32proc.json",
                "expert_before": "results/demos/bench-expert-before-train40.json",
                "expert_fast": "results/demos/bench-expert-fast-train40.json",
                "expert_node": "results/training/imitation-rounds/expert-x4-train0-700.json"}
PAPER_TRAJECTORIES = 27_500


def costs_block() -> str:
    """The cost tables of docs/imitation-rounds.md, from the records in ``COST_RECORDS``."""
    r = {k: json.loads((ROOT / v).read_text()) for k, v in COST_RECORDS.items()}
    modes = ("compact_pointcloud", "policy_pointcloud", "composed_pointcloud")
    lines = ["| obs mode | 2-core CPU, ms a frame (frames/s) | 32-core node, 2 H200, one process: ms a frame (frames/s) |",
             "| --- | --- | --- |"]
    for m in modes:
        a, b = r["cpu2"]["ms_a_frame"][m], r["node"]["ms_a_frame"][m]
        lines.append(f"| `{m}` | {a:.1f} ({1e3 / a:.0f}) | {b:.1f} ({1e3 / b:.0f}) |")
    ratio = [r[k]["ms_a_frame"]["compact_pointcloud"] / r[k]["ms_a_frame"]["composed_pointcloud"] for k in ("cpu2", "node")]
    n32 = r["node32"]
    lines += ["", f"`composed_pointcloud` is {ratio[0]:.1f}x cheaper a frame than `compact_pointcloud` on the 2-core "
              f"CPU and {ratio[1]:.1f}x in one process of the node (its start render: "
              f"{r['cpu2']['composed_start_ms_an_episode']:.0f} and {r['node']['composed_start_ms_an_episode']:.0f} ms "
              f"an episode, included at stride {r['cpu2']['frame_stride']}); {n32['processes']} processes at once on the "
              f"node make **{n32['frames_a_second']:,.0f} frames a second**. A state-only replay step (converting the "
              f"expert's actions) costs {r['cpu2']['replay_step_ms']:.1f} / {r['node']['replay_step_ms']:.1f} ms.", ""]
    before, fast, node = r["expert_before"], r["expert_fast"], r["expert_node"]
    lines += ["| expert | where | tasks | yield | trajectories | a CPU-hour | a worker-hour (wall) |",
              "| --- | --- | --- | --- | --- | --- | --- |"]
    for name, e in (("`reference`", before), ("`fast`", fast)):
        lines.append(f"| {name} | 2-core CPU, 1 worker | train 0:{e['tasks']} | {e['tasks_with_demo']:.3f} | "
                     f"{e['trajectories']} | {e['trajectories_per_cpu_hour']:,.0f} | {e['trajectories_per_core_hour']:,.0f} |")
    lines.append(f"| `reference` | 64-core node, 64 workers | train 0:{node['tasks']} | {node['yield']:.3f} | "
                 f"{node['trajectories']} | - | {node['trajectories_per_core_hour']:,.0f} |")
    rounds = load_record(RECORD)["rounds"]
    for entry in rounds:  # each round's expert, as its record gives it
        e = entry["expert"]
        lines.append(f"| `{e['expert']}` | round {entry['round']}: {entry.get('machine', 'the node')} | "
                     f"train {entry['tasks'][0]}:{entry['tasks'][1]} | {e['yield']:.3f} | {e['trajectories']} | - | "
                     f"{e['trajectories_per_core_hour']:,.0f} |")
    rate = rounds[-1]["expert"]["trajectories_per_core_hour"] if rounds else node["trajectories_per_core_hour"]
    hours = PAPER_TRAJECTORIES / rate
    frames = PAPER_TRAJECTORIES * fast["mean_frames"] / r["cpu2"]["frame_stride"]
    if rounds:
        last = rounds[-1]
        lines += ["", f"Round {last['round']} made its {last['demos']:,} demonstrations' {last['frames']:,} frames at the "
                  f"expert's own states (no replay) at {last['expert']['conversion_frames_per_second']:,.0f} frames a "
                  f"second, the render processes' start included."]
    lines += ["", f"The paper's {PAPER_TRAJECTORIES:,} demonstrations on one 32-core node with two H200s, at these "
              f"rates: the expert {hours:.0f} worker-hours at the node's last measured rate ({hours / 32:.1f} h on 32 "
              f"workers), and their ~{frames / 1e6:.1f} M frames at stride {r['cpu2']['frame_stride']} "
              + (f"{frames / rounds[-1]['expert']['conversion_frames_per_second'] / 60:.0f} minutes at round "
                 f"{rounds[-1]['round']}'s conversion rate ({frames / n32['frames_a_second'] / 60:.0f} at the "
                 f"{n32['processes']}-process rate of composing alone, without the resets and renders of the episodes' "
                 "starts)." if rounds else
                 f"{frames / n32['frames_a_second'] / 60:.0f} minutes of `composed_pointcloud` observations at the "
                 f"node's {n32['processes']}-process rate.")]
    return "\n".join(lines)


def plot(record: dict, out: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.0))
    for kind in KINDS:
        for method, (line, marker) in zip(methods(kind), (("-", "o"), ("--", "s"))):
            runs = [r["kinds"][kind] for r in record["rounds"] if kind in r["kinds"]]
            if not runs:
                continue
            # a candidate joins the point of the checkpoint it went on from; one from scratch stands alone
            at = {k["demos_seen"]: k["val"][method]["success_rate"] for k in runs}
            colour = ax.plot([k["demos_seen"] for k in runs], [k["val"][method]["success_rate"] for k in runs],
                             marker, linestyle="none", label=method)[0].get_color()
            for k in runs:
                parent = k["init_from"]["demos_seen"] if k["init_from"].get("path") else None
                if parent in at:
                    ax.plot([parent, k["demos_seen"]], [at[parent], k["val"][method]["success_rate"]], line,
                            color=colour)
    ax.set_xlabel("demonstrations seen by the checkpoint's lineage")
    ax.set_ylabel(f"val success ({record['val'].get('tasks', VAL_TASKS)})")
    ax.set_title(f"Imitation rounds ({record['obs_mode']}, frame stride {record['frame_stride']})")
    ax.grid(alpha=0.3)
    ax.legend(fontsize=7, ncol=2)
    fig.tight_layout()
    out.parent.mkdir(parents=True, exist_ok=True)
    # (matplotlib writes no date into a PNG without metadata: same record, same bytes)
    fig.savefig(out, dpi=110, metadata={"Software": None})
    print(f"wrote {out}")


def main(argv=None) -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--record", type=Path, default=RECORD, help="the rounds' record folder (rounds.json)")
    p.add_argument("--status", action="store_true", help="print where the rounds stand and exit")
    p.add_argument("--plot", type=Path, default=None, help="write the validation curve PNG here and exit")
    p.add_argument("--costs", action="store_true",
                   help="print the cost tables of docs/imitation-rounds.md from their records and exit")
    p.add_argument("--work", type=Path, default=None, help="work folder (round_NN/ inside; re-running resumes)")
    p.add_argument("--tasks", type=int, default=600, help="train tasks this round takes, after the last round's")
    p.add_argument("--per-task", type=int, default=3, help="expert trajectories a task at most")
    p.add_argument("--expert", default="fast", choices=("fast", "fast2", "fast3", "reference"),
                   help="the expert's configuration (solutions.expert.EXPERTS; default fast)")
    p.add_argument("--procs", type=int, default=os.cpu_count(), help="expert, replay and eval processes")
    p.add_argument("--gpus", default="0,1", help="GPU indices the trainers take in turn, or 'cpu'")
    p.add_argument("--kinds", default=",".join(KINDS), help=f"policy kinds, comma-separated, of {', '.join(KINDS)}")
    p.add_argument("--steps", default=None, help="KIND=N,...: training steps this round (default "
                                                 + ",".join(f"{k}={v}" for k, v in DEFAULT_STEPS.items()) + ")")
    p.add_argument("--chunk", type=int, default=512,
                   help="demos per conversion chunk: each chunk starts its replay and render processes anew, so "
                        "a chunk of several demos a process amortises their start")
    p.add_argument("--time-limit", type=float, default=420.0, help="s: a trainer's safety net (its steps are recorded)")
    p.add_argument("--trainer-args", default="", help="more flags for every trainer (tests: tiny networks)")
    p.add_argument("--val-tasks", default=VAL_TASKS, help=f"val START:END (at least {MIN_VAL_TASKS} tasks)")
    p.add_argument("--allow-small-val", action="store_true", help="fewer val tasks (tests; recorded as such)")
    p.add_argument("--ship", action="store_true", help="write the winners to assets/checkpoints/ (else only report)")
    args = p.parse_args(argv)
    record = load_record(args.record)
    if answer_report(args, record, costs_block, status, plot):
        return 0
    if args.work is None:
        p.error("--work is needed to run a round (or --status / --plot)")
    kinds = [k for k in args.kinds.split(",") if k]
    if not kinds or set(kinds) - set(KINDS) or len(set(kinds)) != len(kinds):
        p.error(f"--kinds {args.kinds!r}: distinct kinds of {', '.join(KINDS)}")
    if args.tasks < 1 or args.per_task < 1 or args.procs < 1:
        p.error("--tasks, --per-task and --procs must be >= 1")
    gpus = None if args.gpus == "cpu" else [g for g in args.gpus.split(",") if g.isdigit()]
    if gpus is not None and not gpus:
        p.error(f"--gpus {args.gpus!r}: GPU indices (0,1) or 'cpu'")
    steps = parse_steps(args.steps)
    val = parse_slice(args.val_tasks, "--val-tasks", VAL_TASKS)
    if val[1] - val[0] < MIN_VAL_TASKS and not args.allow_small_val:
        p.error(f"--val-tasks {args.val_tasks}: at least {MIN_VAL_TASKS} val tasks choose a checkpoint "
                "(--allow-small-val for a test)")
    made = (record["obs_mode"], record["frame_stride"], record.get("labels", "replay"))
    if record["rounds"] and made != (OBS_MODE, FRAME_STRIDE, LABELS):
        raise SystemExit(f"{args.record}: rounds of {made[0]} at stride {made[1]}, labels {made[2]}; this code "
                         f"makes {OBS_MODE} at stride {FRAME_STRIDE}, labels {LABELS}")
    number = len(record["rounds"]) + 1
    start, end = next_tasks(record, args.tasks)
    work = args.work / f"round_{number:02d}"
    log = round_log(work / "round.log")
    command = shlex.join(["python", "scripts/imitation/imitation_round.py", *(argv if argv is not None else sys.argv[1:])])
    log(f"round {number}: train tasks {start}:{end}; {command}")
    py = sys.executable
    t0 = time.perf_counter()
    # 1. data
    run([py, "scripts/imitation/build_imitation_data.py", "--root", str(work), "--tasks", f"{start}:{end}",
         "--per-task", str(args.per_task), "--expert", args.expert, "--procs", str(args.procs), "--obs-mode", OBS_MODE,
         "--frame-stride", str(FRAME_STRIDE), "--labels", LABELS, "--chunk", str(args.chunk), "--device", "cpu" if gpus is None else "cuda",
         "--render-gpus", str(1 if gpus is None else len(gpus))], log)
    t_data = time.perf_counter() - t0
    manifest = json.loads((work / "data/manifest.json").read_text())
    build = json.loads((work / "build.json").read_text())

    # 2. training, from the shipped checkpoint of the kind where it reads this obs mode
    from fetchbench_ms.policies.agent import checkpoint_obs_mode

    inits, flags = {}, {}
    for kind in kinds:
        path, meta = shipped(kind)
        init = path if checkpoint_obs_mode(path) == OBS_MODE else None
        first = int(meta.get("step", 0)) if init else 0
        inits[kind] = {"path": str(init.relative_to(ROOT)) if init else None, "step": first,
                       "sha256": meta.get("checkpoint_sha256") if init else None,
                       "demos_seen": int(meta.get("demos_seen", 0)) if init else 0}
        flags[kind] = f"--steps {first + steps[kind]} --export --export-path {work / 'export' / f'imit_{kind}.pt'}"
        if init:
            flags[kind] += f" --init-from {init} --new-data"
    # A kind whose export finished its steps is not trained again: a resumed trainer exports anew
    # (other bytes), and its val records would no longer name the file they judged.
    todo = [kind for kind in kinds
            if not export_complete(work / "export" / f"imit_{kind}.json", inits[kind]["step"] + steps[kind])]
    kind_args = [a for kind in todo for a in ("--kind-args", f"{kind}={flags[kind]}")]
    t1 = time.perf_counter()
    if todo:
        gpu_list = "cpu" if gpus is None else ",".join(gpus[i % len(gpus)] for i in range(len(todo)))
        run([py, "scripts/imitation/train_imitation_gpus.py", "--data", str(work / "data"), "--runs", str(work / "runs"),
             "--kinds", ",".join(todo), "--gpus", gpu_list, "--time-limit", str(args.time_limit),
             "--trainer-args", f"--eval-every 0 {args.trainer_args}".strip(), *kind_args], log)
    t_train = time.perf_counter() - t1
    (work / "logs").mkdir(exist_ok=True)
    for kind in kinds:  # ship_imitation.py's layout: logs/train_<kind>.log
        (work / "logs" / f"train_{kind}.log").write_text((work / "runs" / kind / "log.txt").read_text())

    # 3. val: every candidate end to end and as the hybrid (resumable eval folders), all at once:
    # the --procs workers shared among them (one start-up for all), each eval on a GPU in turn.
    t2 = time.perf_counter()
    # (kind, method, checkpoint or None for the shipped one, folder): every candidate's runs, and
    # the shipped checkpoint's runs it has no val figures of on these tasks (judged alike, once).
    evals = [(kind, method, work / "export" / f"imit_{kind}.pt", work / "val" / method)
             for kind in kinds for method in methods(kind)]
    shipped_now = {kind: shipped(kind) for kind in kinds}
    evals += [(kind, method, None, work / "val-shipped" / method) for kind in kinds for method in methods(kind)
              if val_successes(shipped_now[kind][1], method, val) is None]
    # Twice --procs workers in all: the runs' costs differ (an end-to-end run on compact_pointcloud
    # is the slowest), and the slow ones keep the cores busy once the fast ones have ended.
    workers = max(1, 2 * args.procs // len(evals))
    processes = []
    for i, (kind, method, checkpoint, out) in enumerate(evals):
        eval_command = [py, "-m", "fetchbench_ms", "eval", "--method", method, "--suite", "val", "--tasks",
                        args.val_tasks, "--policy-stride", str(FRAME_STRIDE), "--workers", str(workers), "--out", str(out)]
        if checkpoint is not None:
            eval_command += ["--policy-checkpoint", str(checkpoint)]
        if method.startswith("cgn-imit-"):
            eval_command += ["--planner-option", f"trajopt_counts={HYBRID_TRAJOPT_COUNTS}"]
        env = dict(os.environ)
        if gpus is not None:
            env["CUDA_VISIBLE_DEVICES"] = gpus[i % len(gpus)]
        log(f"$ {shlex.join(eval_command)}")
        out.mkdir(parents=True, exist_ok=True)
        processes.append((out, subprocess.Popen(eval_command, cwd=ROOT, env=env, stdout=open(out / "eval.log", "a"),
                                                stderr=subprocess.STDOUT)))
    failed = [f"{out.name} (exit {code}, {out / 'eval.log'})" for out, process in processes if (code := process.wait()) != 0]
    if failed:
        raise SystemExit(f"stopped: val runs failed: {', '.join(failed)}; run the same command to resume")
    figures = {kind: {} for kind in kinds}
    shipped_figures = {kind: {} for kind in kinds}  # the shipped checkpoint's runs made here
    for kind, method, checkpoint, out in evals:
        successes, n = eval_successes(out)
        (figures if checkpoint is not None else shipped_figures)[kind][method] = {
            "successes": successes, "tasks": n, "success_rate": round(successes / n, 4),
            "run": str(out.relative_to(args.work))}
    t_val = time.perf_counter() - t2

    # 4. choice (and shipping), 5. record
    entry = {"round": number, "tasks": [start, end], "per_task": args.per_task, "demos": manifest["totals"]["demos"],
             "frames": manifest["totals"]["frames"], "chunks": len(manifest["chunks"]),
             "source_sha256": manifest["settings"]["source_sha256"],
             "data_sha256": json.loads((work / "export" / f"imit_{kinds[0]}.json").read_text())["data_sha256"],
             "expert": {k: build[k] for k in ("expert", "trajectories", "tasks_timed", "tasks_with_a_trajectory", "yield",
                                              "trajectories_per_core_hour", "conversion_frames_per_second")},
             "command": command, "val_tasks": args.val_tasks,
             "small_val": bool(args.allow_small_val and val[1] - val[0] < MIN_VAL_TASKS),
             "seconds": {"data": round(t_data), "training": round(t_train), "val": round(t_val)},
             "machine": machine(gpus), "kinds": {}}
    winners = []
    for kind in kinds:
        _, meta = shipped_now[kind]
        export_meta = json.loads((work / "export" / f"imit_{kind}.json").read_text())
        judged = {**meta, "validation_success": meta.get("validation_success", []) + [
            {"method": m, "first_task": f"val/{val[0]:04d}", "last_task": f"val/{val[1] - 1:04d}",
             "successes": v["successes"]} for m, v in shipped_figures[kind].items()]}
        choice = choose({m: v["successes"] for m, v in figures[kind].items()}, judged, val)
        demos_seen = inits[kind]["demos_seen"] + entry["demos"]
        entry["kinds"][kind] = {"init_from": inits[kind], "steps": [inits[kind]["step"], int(export_meta["step"])],
                                "demos_seen": demos_seen, "val": figures[kind], "shipped_val": shipped_figures[kind],
                                "choice": choice,
                                "shipped": bool(choice["ships"] and args.ship)}
        if choice["ships"]:
            winners.append(kind)
            export_meta["demos_seen"] = demos_seen  # the lineage's data, rounds included
            export_meta["rounds"] = [r["round"] for r in record["rounds"] if r["kinds"].get(kind, {}).get("shipped")
                                     and inits[kind]["path"]] + [number]
            (work / "export" / f"imit_{kind}.json").write_text(json.dumps(export_meta, indent=1))
        val_text = ", ".join(f"{m} {v['successes']}/{v['tasks']}" for m, v in figures[kind].items())
        log(f"{kind}: {val_text}; {'ships' if choice['ships'] else 'stays'}: {choice['why']}")
    kept = [out for kind, method, checkpoint, out in evals if checkpoint is None and kind not in winners]
    if args.ship and kept:  # the shipped checkpoints that stay keep their new val figures
        run([py, "scripts/maint/ship_imitation.py", "--val-runs", *map(str, kept)], log)
    if args.ship and winners:
        val_runs = [str(work / "val" / m) for k in winners for m in methods(k)]
        run([py, "scripts/maint/ship_imitation.py", "--run", str(work), "--kinds", ",".join(winners),
             "--retrain", command, "--note", f"imitation round {number} (scripts/imitation/imitation_round.py --status)",
             "--val-runs", *val_runs], log)
    record.setdefault("val", {})["tasks"] = args.val_tasks
    record["rounds"].append(entry)
    args.record.mkdir(parents=True, exist_ok=True)
    from fetchbench_ms.utils.io import atomic_write_text

    atomic_write_text(args.record / "rounds.json", json.dumps(record, indent=1) + "\n")
    log(f"round {number} recorded in {args.record / 'rounds.json'} ({time.perf_counter() - t0:.0f} s: data "
        f"{t_data:.0f}, training {t_train:.0f}, val {t_val:.0f})")
    print(status(record))
    return 0


if __name__ == "__main__":
    sys.exit(main())

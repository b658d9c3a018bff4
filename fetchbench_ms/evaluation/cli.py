"""``fetchbench eval`` (run a method on suite tasks or env seeds) and ``fetchbench report``."""
from __future__ import annotations

import os
import sys

from ..method_spec import PIPELINES, POLICY_KINDS
from .runner import BACKENDS


def default_out(run, labels_arg=None) -> str:
    """``out/eval/<method>[-<weights>][-<pipeline>][-<option>=<value>...][-robot=R][-labels=DIR]``."""
    name = run.name.replace(":", "_") + (f"-{run.grasp_model}" if run.method.grasps == "cgn" else "")
    if run.method.has_pipeline:
        name += f"-{run.pipeline_fields()['pipeline']}"
    name += "".join(f"-{k}={v}" for k, v in [*run.env_options, *run.planner_options])
    if run.robot != "panda":
        name += f"-robot={run.robot}"
    if labels_arg is not None:
        name += f"-labels={os.path.basename(os.path.normpath(labels_arg))}"
    return os.path.join("out", "eval", name)


def cmd_eval(args) -> int:
    from ..method_spec import pipeline_improvements
    from ..solutions.planner_options import check_planner_options, parse_planner_options
    from .metrics import format_table, summarize
    from .methods import resolve_method, resolve_run
    from .runner import evaluate_run

    if args.suite is not None and args.env is not None:
        raise ValueError("give --suite (suite tasks) or --env with --episodes/--seed (sampled tasks), not both")
    if args.tasks is not None and args.suite is None:
        raise ValueError("--tasks selects tasks of a --suite")
    method = resolve_method(args.method)
    # a bad planner option is answered here, before the envs, torch and the planners load
    planner_options = check_planner_options(method, parse_planner_options(args.planner_option or []))
    without = [w.strip() for w in (args.without or "").split(",") if w.strip()]
    if not method.has_pipeline and (args.pipeline != "paper" or without):
        raise ValueError(f"{method.name} runs no sense-plan-act pipeline: --pipeline / --without do not apply")
    from ..envs import parse_env_options

    run = resolve_run(method, args.retries, args.grasp_model, args.policy_checkpoint, args.policy_stride,
                      pipeline_improvements(args.pipeline, without), args.grasp_labels, planner_options,
                      parse_env_options(args.env_option or []), args.robot)
    out = args.out or default_out(run, args.grasp_labels)
    records = evaluate_run(run, out, suite=args.suite, tasks=args.tasks, env_id=args.env, episodes=args.episodes,
                           seed=args.seed, workers=args.workers, backend=args.backend, address=args.address,
                           task_timeout=args.task_timeout, retry_errors=args.retry_errors, videos=args.videos)
    for r in records:
        if r.get("error"):
            print(f"{r['task_id']}: {r['error']['kind']}: {r['error']['message']}")
    summary = summarize(records)
    print(format_table(summary, "by_category"))
    print(f"results: {os.path.join(out, 'results.jsonl')}")
    if records and all(r.get("error") for r in records):
        print(f"fetchbench: every one of the {len(records)} tasks ended in an error: nothing was evaluated",
              file=sys.stderr)
        return 1
    return 0


def cmd_report(args) -> int:
    from .report import build_report

    page = build_report(args.results, args.out, gallery=args.gallery, render=not args.no_render)
    print(f"report: {page}")
    return 0


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("eval", help="evaluate a method on a task suite (one JSON line per task, resumable)")
    # (The help names kinds, not every method: listing them would load torch and the planners
    # before a flag is read; an unknown name is answered with the full list.)
    p.add_argument("--method", default="ga-mesh-rrt",
                   help="a built-in method: sense-plan-act ga-{mesh,ptd}-{rrt,trajopt}, cgn-{mesh,ptd}-{rrt,trajopt}, "
                        f"cgn-ptd-mppi, ...; imitation e2e-KIND, twostage-KIND, cgn-imit-KIND (KIND: "
                        f"{', '.join(POLICY_KINDS)}); idle (an unknown name lists them all); or an importable "
                        "module:function")
    p.add_argument("--grasp-model", default="pretrained", choices=("pretrained", "ours"),
                   help="cgn-* methods: Contact-GraspNet weights (pretrained: from the cgn-pytorch package; "
                        "ours: assets/checkpoints/cgn_ours.pt)")
    p.add_argument("--policy-checkpoint", default=None,
                   help="e2e-* / twostage-* / cgn-imit-* methods: the policy checkpoint (default: assets/checkpoints/imit_KIND.pt)")
    p.add_argument("--policy-stride", type=int, default=1, metavar="K",
                   help="e2e-* / twostage-* / cgn-imit-* methods: the policy observes and acts every K control "
                        "steps, repeating its arm action in between (1: every step, as trained; an ACT policy "
                        "ensembles a chunk from each observation; a diffusion policy runs its action chunks and "
                        "checks termination every K steps)")
    p.add_argument("--pipeline", default="paper", choices=tuple(PIPELINES),
                   help="sense-plan-act methods and hybrids: 'paper' runs the original's step list (the rows "
                        "named after the paper's methods); 'ours' adds our improvements "
                        "(retreat, extra_lifts, start_escape, cgn_filter), recorded in run.json and every record")
    p.add_argument("--without", default=None, metavar="NAME[,NAME]",
                   help="with --pipeline ours: switch these improvements off (an unknown name lists them)")
    p.add_argument("--env-option", action="append", default=None, metavar="KEY=VALUE",
                   help="an env option of the ablation, e.g. sim_freq=60 or camera_placement=paper "
                        "(repeatable; recorded in run.json and every record)")
    p.add_argument("--planner-option", action="append", default=None, metavar="KEY=VALUE",
                   help="a planner parameter of the ablation, for the MPPI methods: mppi_goal_region=RAD (the goal "
                        "credit's region, 0: off) or mppi_cost=network|distance; for the trajopt methods and the "
                        "hybrids: trajopt_counts=SEEDSxITERSxSUBSTEPS (default 8x40x2), trajopt_loop=eager|graph|grid|cpu "
                        "(the Adam loop; default eager) or trajopt_certify=RAD|off (certified checks; default off) "
                        "(repeatable; recorded in "
                        "run.json and every record)")
    from ..robots import DEFAULT_ROBOT, ROBOT_UIDS

    p.add_argument("--robot", default=DEFAULT_ROBOT, choices=ROBOT_UIDS,
                   help="the hardware setup (the env's robot_uids; docs/robots.md): the sense-plan-act methods "
                        "run on every one; recorded in run.json and every record unless the Panda")
    p.add_argument("--grasp-labels", default=None, metavar="DIR",
                   help="ga-* methods: the annotated grasps' store (default: the shipped Franka-hand labels; "
                        "e.g. the Robotiq's, built by `fetchbench grasps build --hand robotiq_2f_85`); recorded")
    p.add_argument("--suite", default=None, help="task suite: test, val, smoke, or a suite file")
    p.add_argument("--tasks", default=None, help="START:END slice of the suite's tasks, e.g. 0:600")
    p.add_argument("--env", default=None,
                   help="instead of a suite: sample tasks from this env id's seeds, with test-split objects "
                        "(an evaluation; the env's own default for seeds is the train split)")
    p.add_argument("--episodes", type=int, default=10, help="with --env: number of seeds (default %(default)s)")
    p.add_argument("--seed", type=int, default=0, help="with --env: first seed (default %(default)s)")
    p.add_argument("--workers", type=int, default=1, help="worker processes, one core each (default %(default)s)")
    p.add_argument("--backend", default="local", help=f"one of: {', '.join(BACKENDS)}")
    p.add_argument("--address", default=None, help="ray: address of an existing cluster (default: start a local one)")
    p.add_argument("--task-timeout", type=float, default=600.0,
                   help="s a task's method may run, counted from its start in the worker (its env made and "
                        "reset), before it is killed: a safety net only (budgets are counts); such a task is "
                        "recorded as failure 'timeout' (default %(default)s)")
    p.add_argument("--retries", type=int, default=1, help="tries per task (default %(default)s; FetchBench's --retries 5)")
    p.add_argument("--retry-errors", action="store_true", help="run again the tasks recorded as errors")
    p.add_argument("--videos", action="store_true",
                   help="record a GIF of every failed task (OUT/videos/), shown in the report's gallery")
    p.add_argument("--out", default=None, help="results directory, default out/eval/METHOD (re-running resumes)")
    p.set_defaults(func=cmd_eval)

    r = subparsers.add_parser("report", help="HTML report of one or more results directories")
    r.add_argument("results", nargs="+", help="results directories (several: compared side by side)")
    r.add_argument("--out", default=None, help="report folder (default: FIRST_DIR/report)")
    r.add_argument("--gallery", type=int, default=6, help="sample failures pictured per method")
    r.add_argument("--no-render", action="store_true", help="no start images (no renderer needed)")
    r.set_defaults(func=cmd_report)

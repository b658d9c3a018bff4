"""``fetchbench eval``: run a sense-plan-act baseline on sampled FetchBench tasks."""
from __future__ import annotations

from .sense_plan_act import METHODS


def cmd_eval(args) -> int:
    from .runner import format_summary, run_episodes, summarize

    if args.method not in METHODS:
        raise ValueError(f"unknown method {args.method!r}; valid: {', '.join(METHODS)}")
    from ..envs import ENV_IDS

    if args.env not in ENV_IDS:
        raise ValueError(f"unknown env id {args.env!r}; valid: {', '.join(ENV_IDS)}")
    records = run_episodes(args.method, args.env, args.episodes, args.seed, args.out, retries=args.retries,
                           reachable_only=args.reachable_only)
    skipped = [r for r in records if "skipped" in r]
    for r in skipped:
        print(f"seed {r['seed']} skipped: {r['skipped']}")
    summary = summarize(records)
    print(format_summary(summary) if summary else "no episode ran")
    return 0


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("eval", help="evaluate a sense-plan-act baseline (one JSON line per episode)")
    p.add_argument("--method", default="ga-mesh-rrt", help=f"one of: {', '.join(METHODS)}")
    p.add_argument("--env", default="FetchBench-v0", help="a FetchBench env id, e.g. FetchBench-Shelf-v0")
    p.add_argument("--episodes", type=int, default=10)
    p.add_argument("--seed", type=int, default=0, help="episodes use seeds seed .. seed+episodes-1")
    p.add_argument("--retries", type=int, default=1, help="tries per episode (FetchBench's --retries 5)")
    p.add_argument("--reachable-only", action="store_true",
                   help="skip tasks failing FetchBench's reachability filter (no collision-free grasp IK)")
    p.add_argument("--out", default=None, help="directory for episodes.jsonl and summary.json (resumable)")
    p.set_defaults(func=cmd_eval)

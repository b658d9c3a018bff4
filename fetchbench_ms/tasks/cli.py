"""`fetchbench tasks sample`: draw a task from a seed and print or save it as JSON."""
from __future__ import annotations

import json


def _sample(args) -> int:
    from ..utils.io import atomic_write_text
    from .sampler import SamplerConfig, sample_task

    task = sample_task(args.seed, scene_type=args.scene_type, category=args.category,
                       config=SamplerConfig(num_objects=args.objects, object_split=args.split))
    text = json.dumps(task.to_dict(), indent=1, sort_keys=True)
    if args.out:
        atomic_write_text(args.out, text + "\n")
        print(f"wrote {args.out}: {task.scene_type} scene, {len(task.objects)} objects, "
              f"target {task.target.object_id} ({task.target_label})")
    else:
        print(text)
    return 0


def add_commands(subparsers) -> None:
    tasks = subparsers.add_parser("tasks", help="fetching tasks: sample one from a seed")
    sub = tasks.add_subparsers(dest="tasks_command", required=True, metavar="ACTION")
    s = sub.add_parser("sample", help="sample a task (scene, objects, robot, cameras) as JSON")
    s.add_argument("--seed", type=int, required=True)
    s.add_argument("--scene-type", default=None, help="one of the 13 scene types (default: the paper's mix)")
    s.add_argument("--category", default=None, help="target support: Table, Shelf, Drawer or Basket (or the "
                   "target labels on_table, on_shelf, in_drawer, in_basket)")
    s.add_argument("--objects", type=int, default=15, help="objects to place (default 15)")
    s.add_argument("--split", default="train", choices=("train", "test"),
                   help="object split (default train, as the envs' seeded resets)")
    s.add_argument("-o", "--out", default=None, help="write the task JSON here instead of printing it")
    s.set_defaults(func=_sample)

    from .suite_cli import add_commands as add_suite_commands

    add_suite_commands(subparsers)

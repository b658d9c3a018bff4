"""``fetchbench results pack RUN_DIR --name NAME`` and ``fetchbench results table``: the shipped
records in ``results/runs/`` and the tables of docs/results.md printed from them."""
from __future__ import annotations

import sys


def cmd_pack(args) -> int:
    from .results_table import pack

    print(f"packed: {pack(args.run_dir, args.name, args.runs_dir, force=args.force)}")
    return 0


def cmd_table(args) -> int:
    from .results_table import check_doc, load_runs, tables, write_doc

    output = tables(load_runs(args.runs_dir))
    if args.write:
        print(f"{args.write}: {'rewritten' if write_doc(args.write, output) else 'already up to date'}")
    if args.check:
        problem = check_doc(args.check, output)
        if problem:
            print(problem, file=sys.stderr)
            return 1
        print(f"{args.check}: the tables are the command's output")
    if not (args.write or args.check):
        sys.stdout.write(output)
    return 0


def add_commands(subparsers) -> None:
    p = subparsers.add_parser("results", help="the shipped evaluation records (results/runs) and their tables")
    sub = p.add_subparsers(dest="results_command", required=True, metavar="ACTION")
    k = sub.add_parser("pack", help="pack a results directory (or the shards of one run) into results/runs/NAME "
                                    "(run.json + results.jsonl.xz)")
    k.add_argument("run_dir", metavar="RUN_DIR", nargs="+",
                   help="a results directory of `fetchbench eval --out`; several: shards of one run "
                        "(the same method and options, --tasks ranges that tile one range), packed as one run")
    k.add_argument("--name", required=True, help="the run's stable name, e.g. cgn-ptd-rrt-pretrained-test600")
    k.add_argument("--force", action="store_true", help="replace a packed run of that name that holds another run")
    k.add_argument("--runs-dir", default=None, help="where packed runs live (default: the checkout's results/runs)")
    k.set_defaults(func=cmd_pack)
    t = sub.add_parser("table", help="print the Markdown tables of every packed run (docs/results.md's)")
    t.add_argument("--check", metavar="DOC", default=None,
                   help="exit 1 naming the first line where DOC's tables differ from the output")
    t.add_argument("--write", metavar="DOC", default=None, help="rewrite DOC's tables with the output")
    t.add_argument("--runs-dir", default=None, help="where packed runs live (default: the checkout's results/runs)")
    t.set_defaults(func=cmd_table)

"""The ``fetchbench`` command. Each sub-package that has a ``cli`` module adds its own
sub-commands through ``add_commands(subparsers)``, so features stay in their folders."""
from __future__ import annotations

import argparse
import importlib
import sys
from pathlib import Path

PACKAGE_DIR = Path(__file__).resolve().parent

# Sub-packages that may contribute commands, in the order they appear in --help.
COMMAND_PACKAGES = ("scenes", "objects", "grasp_labels", "envs", "tasks", "solutions", "demos", "evaluation")
# Further command modules (a package's second set of commands).
COMMAND_MODULES = ("fetchbench_ms.evaluation.results_cli",)
# Sub-packages that add sub-commands to another package's command: package -> that command
# (its ``add_commands`` returns its sub-commands). ``fetchbench grasps predict`` is grasp prediction's.
SUBCOMMAND_PACKAGES = {"grasp_prediction": "grasp_labels"}


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(prog="fetchbench", description="FetchBench-MS: fetching benchmark on ManiSkill3")
    subparsers = parser.add_subparsers(dest="command", required=True, metavar="COMMAND")
    commands = {}
    for package in COMMAND_PACKAGES:
        # Only a package without a cli module is skipped; a cli module that fails to import
        # is a real error and is raised. (Looked for as a file: find_spec of a sub-module
        # would import its package, and a package may load torch.)
        if not (PACKAGE_DIR / package / "cli.py").is_file():
            continue
        commands[package] = importlib.import_module(f"fetchbench_ms.{package}.cli").add_commands(subparsers)
    for package, command in SUBCOMMAND_PACKAGES.items():
        importlib.import_module(f"fetchbench_ms.{package}.cli").add_commands(commands[command])
    for module_name in COMMAND_MODULES:
        importlib.import_module(module_name).add_commands(subparsers)
    # The main job (`make demo`); its content changes as the project grows.
    importlib.import_module("fetchbench_ms.demo").add_commands(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    try:
        result = args.func(args)
    except (ValueError, KeyError, FileNotFoundError) as error:
        # Bad input: one clear line that names what is valid, no traceback.
        message = error.args[0] if isinstance(error, KeyError) and error.args else error
        print(f"fetchbench: error: {message}", file=sys.stderr)
        return 2
    except (PermissionError, NotADirectoryError, IsADirectoryError) as error:
        # A path given that cannot be written or read as asked (an output folder that is a
        # file, a folder without permission): the user's to fix, so one line too.
        print(f"fetchbench: error: {error.strerror}: {error.filename}", file=sys.stderr)
        return 2
    return int(result or 0)


if __name__ == "__main__":
    sys.exit(main())

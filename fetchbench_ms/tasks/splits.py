"""The guard that keeps the test split out of training and out of every choice.

The rule: test-split objects and test-suite tasks are never used for training or for any
choice (hyper-parameters, checkpoints, fixes); choices use the ``val`` suite, learning the
``train`` suite (or seed-sampled tasks, which use train-split objects); the test suite is
run once per shipped configuration, through ``fetchbench eval`` only.

Every script that trains, makes training data or selects calls one of the ``refuse_*``
checks below before it does any work or writes any file::

    from fetchbench_ms.tasks.splits import refuse_test
    refuse_test(args.suite, "checkpoint selection")   # raises TestSplitRefused (a ValueError)

    from fetchbench_ms.tasks.splits import cli_guard
    cli_guard(refuse_test, args.suite, "PPO training")  # a script's CLI: one line on stderr, exit 2

What counts as test:

- a suite (a shipped name, the path of a suite file, or a loaded ``TaskSuite``) named
  ``test``, or whose recipe used ``object_split="test"`` (``info["recipe"]``), or that was cut
  from a test suite (``info["source_suite"]``, as ``smoke`` is), or that holds a test-split
  object (``objects.catalog.split_of``, a hash of the object id);
- ``object_split="test"`` (an env's or the sampler's);
- a task id whose suite part (``test/0042``) names such a shipped suite;
- an object id of the test split;
- an eval folder (``fetchbench eval --out``) of such a suite (its ``run.json``: suite name
  and file hash, and its records' task ids).
"""
from __future__ import annotations

import functools
import json
import sys
from pathlib import Path
from typing import Callable, Iterable

TEST = "test"
ADVICE = "use train (learning) or val (choices)"


class TestSplitRefused(ValueError):
    """A training, data-making or selection step was given test tasks or test objects."""

    __test__ = False  # (not a pytest test class)


def refusal(purpose: str, what: str = "the test suite") -> str:
    """The one-line message of a refusal."""
    return (f"{purpose} refuses {what}: test tasks are never used for training or selection; {ADVICE}")


# ----------------------------------------------------------------------------- what is test
def is_test_object(object_id: str) -> bool:
    from ..objects.catalog import split_of

    return split_of(str(object_id)) == TEST


@functools.lru_cache(maxsize=32)
def _file_is_test(path: str, mtime_ns: int, size: int) -> bool:
    """Whether a suite file's content is test (read as raw JSON: no tasks are built)."""
    from .suite import suite_text

    body = json.loads(suite_text(Path(path).read_bytes(), path))
    return _body_is_test(body.get("name"), body.get("info") or {},
                         (o.get("object_id") for a in body.get("arrangements", []) for o in a.get("objects", [])))


def _body_is_test(name, info: dict, object_ids: Iterable[str]) -> bool:
    if name == TEST:
        return True
    if (info.get("recipe") or {}).get("object_split") == TEST:
        return True
    source = info.get("source_suite")
    if source is not None and source != name and suite_is_test(source):
        return True
    return any(is_test_object(o) for o in set(object_ids) if o)


def suite_is_test(suite) -> bool:
    """Whether ``suite`` (a shipped suite name, a suite file's path, or a ``TaskSuite``) is
    the test suite or made of its tasks or objects. An unknown name or a missing file is not
    judged here (False): the caller's own loading reports it."""
    from .suite import TaskSuite, suite_path

    if isinstance(suite, TaskSuite):
        return _body_is_test(suite.name, suite.info,
                             (o.object_id for t in suite.tasks.values() for o in t.objects))
    if suite is None:
        return False
    if str(suite) == TEST:
        return True
    try:
        path = suite_path(suite)
    except (ValueError, FileNotFoundError):
        return False
    stat = path.stat()
    try:
        return _file_is_test(str(path.resolve()), stat.st_mtime_ns, stat.st_size)
    except (OSError, EOFError, ValueError):
        return False  # not a readable suite file: its loader says why


@functools.lru_cache(maxsize=1)
def test_suite_names() -> frozenset:
    """Names of the shipped suites whose content is test (``test``, ``smoke``)."""
    from .suite import shipped_suites

    return frozenset({TEST} | {name for name in shipped_suites() if suite_is_test(name)})


@functools.lru_cache(maxsize=1)
def test_suite_hashes() -> frozenset:
    """The identities of the shipped test-content suite files (``suite.suite_file_sha256``:
    what an eval folder's run.json records as ``source_sha256``)."""
    from .suite import shipped_suite_file, suite_file_sha256

    files = [shipped_suite_file(name) for name in test_suite_names()]
    return frozenset(suite_file_sha256(path) for path in files if path is not None)


def task_id_is_test(task_id: str) -> bool:
    """Whether a task id (``<suite>/<index>``) belongs to a shipped test-content suite."""
    return str(task_id).split("/", 1)[0] in test_suite_names()


# ----------------------------------------------------------------------------- the guards
def refuse_test(suite, purpose: str) -> None:
    """Raise ``TestSplitRefused`` when ``suite`` (name, path or ``TaskSuite``) is test."""
    if suite_is_test(suite):
        name = getattr(suite, "name", suite)
        what = "the test suite" if str(name) == TEST else f"the test suite ({name}: test tasks or objects)"
        raise TestSplitRefused(refusal(purpose, what))


def refuse_test_split(object_split, purpose: str) -> None:
    """Raise ``TestSplitRefused`` for ``object_split="test"``."""
    if object_split == TEST:
        raise TestSplitRefused(refusal(purpose, "the test suite (object_split='test': test-split objects)"))


def refuse_test_env_kwargs(env_kwargs: dict, purpose: str) -> None:
    """An env's keyword arguments: its ``task_suite`` and its ``object_split``."""
    refuse_test_split(env_kwargs.get("object_split"), purpose)
    refuse_test(env_kwargs.get("task_suite"), purpose)


def refuse_test_task_ids(task_ids: Iterable[str], purpose: str) -> None:
    """Raise ``TestSplitRefused`` when a task id belongs to a test-content suite."""
    bad = sorted({str(t) for t in task_ids if t is not None and task_id_is_test(t)})
    if bad:
        shown = ", ".join(bad[:3]) + (f", ... ({len(bad)} in all)" if len(bad) > 3 else "")
        raise TestSplitRefused(refusal(purpose, f"the test suite (tasks {shown})"))


def refuse_test_objects(object_ids: Iterable[str], purpose: str) -> None:
    """Raise ``TestSplitRefused`` when an object id is of the test split."""
    bad = sorted({str(o) for o in object_ids if o and is_test_object(o)})
    if bad:
        shown = ", ".join(bad[:3]) + (f", ... ({len(bad)} in all)" if len(bad) > 3 else "")
        raise TestSplitRefused(refusal(purpose, f"the test suite (test-split objects {shown})"))


def refuse_test_results(run_dir, purpose: str) -> None:
    """An eval folder (``fetchbench eval --out``): its ``run.json`` (suite name, suite file
    hash, env kwargs) and its records' task ids."""
    run_dir = Path(run_dir)
    manifest_path = run_dir / "run.json"
    if manifest_path.is_file():
        manifest = json.loads(manifest_path.read_text())
        selection = manifest.get("selection") or {}
        if selection.get("suite") in test_suite_names() or manifest.get("source_sha256") in test_suite_hashes():
            raise TestSplitRefused(refusal(purpose, f"the test suite ({run_dir} is a run of test tasks)"))
        refuse_test_split(selection.get("object_split"), purpose)  # an --env run of sampled tasks
    results = run_dir / "results.jsonl"
    if results.is_file():
        ids = [json.loads(line).get("task_id") for line in results.read_text().splitlines() if line.strip()]
        refuse_test_task_ids(ids, purpose)


class RefusalExit(SystemExit):
    """A script's exit on a refusal: status 2; ``str()`` is the refusal's line."""

    def __init__(self, message: str):
        super().__init__(2)
        self.message = message

    def __str__(self) -> str:
        return self.message


def cli_guard(check: Callable, *args, **kwargs):
    """Run a ``refuse_*`` check (or any call that may raise ``TestSplitRefused``) for a
    script's command line and return its result: a refusal prints its one line on stderr
    and exits with status 2 (the scripts' usage-error status; ``RefusalExit``)."""
    try:
        return check(*args, **kwargs)
    except TestSplitRefused as error:
        print(f"error: {error}", file=sys.stderr, flush=True)
        raise RefusalExit(str(error)) from None

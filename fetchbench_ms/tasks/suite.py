"""Task suite files: a named, versioned, hashed set of tasks that envs look up by id.

    suite = load_suite("test")            # a shipped suite by name (test, val, smoke) or a path
    task = suite.get("test/0042")         # a TaskSpec
    env = gym.make("FetchBench-v0", task_suite="smoke"); env.reset(options={"task_id": "smoke/0003"})

File (JSON; gzip-compressed when the name ends in ``.gz``; packed, the form the shipped
suites take, when it ends in ``.suite.xz``: ``tasks.suite_packed``), compact because the
tasks of a suite share furniture and object arrangements: every scene is stored once, every
arrangement (objects, robot, cameras of one scene) once, and a task is (id, arrangement,
target index)::

    {"format": "fetchbench-task-suite", "version": "2", "name": ..., "info": {...},
     "scenes": [{scene_type, scene_seed, scene_params, scene_hash}, ...],
     "arrangements": [{"scene": i, <the rest of a TaskSpec dict but target_index>}, ...],
     "tasks": [[task_id, arrangement index, target index], ...],   # in suite order
     "sha256": <sha256 of the canonical JSON of everything else>}

A file whose hash does not match its content, or of another format version, is rejected.
The order of ``tasks`` is the suite order (for the generated suites: any prefix is a
stratified sample, see ``tasks.suite_build``). Every form holds the same canonical JSON;
a run records a suite by ``suite_file_sha256``, the same for each form of one suite.
"""
from __future__ import annotations

import functools
import gzip
import json
from dataclasses import dataclass, field
from pathlib import Path

from ..utils.io import atomic_write_bytes, canonical_json, sha256_bytes
from ..utils.paths import assets_root
from . import suite_packed
from .spec import TaskSpec

SUITE_FORMAT = "fetchbench-task-suite"
SUITE_VERSION = "2"
SCENE_KEYS = ("scene_type", "scene_seed", "scene_params", "scene_hash")
#: The forms of a shipped suite's file, in the order they are looked for.
SHIPPED_SUFFIXES = (suite_packed.SUFFIX, ".json.gz")
_GZIP_MAGIC, _XZ_MAGIC = b"\x1f\x8b", b"\xfd7zXZ\x00"


def suites_dir() -> Path:
    """Where the shipped suites live: ``<name>.suite.xz`` (or ``<name>.json.gz``), in the
    checkout's ``assets/`` or an installed wheel's ``fetchbench_ms/_assets``."""
    return assets_root() / "suites"


def shipped_suites() -> tuple[str, ...]:
    """Names of the suites shipped with the package (test, val, smoke when built)."""
    return tuple(sorted({p.name[: -len(suffix)] for suffix in SHIPPED_SUFFIXES for p in suites_dir().glob(f"*{suffix}")}))


def shipped_suite_file(name: str) -> Path | None:
    """The file of the shipped suite ``name``, or None when none is shipped."""
    return next((p for p in (suites_dir() / f"{name}{s}" for s in SHIPPED_SUFFIXES) if p.is_file()), None)


@dataclass(frozen=True)
class TaskSuite:
    """Tasks by id, in suite order (dict order). ``info``: free-form JSON-safe facts
    about the suite (how it was generated, how complete it is)."""

    name: str
    tasks: dict[str, TaskSpec]
    info: dict = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.tasks)

    def ids(self) -> list[str]:
        return list(self.tasks)

    def get(self, task_id: str) -> TaskSpec:
        if task_id not in self.tasks:
            ids = list(self.tasks)
            shown = ", ".join(ids[:20]) + (f", ... ({len(ids)} in all)" if len(ids) > 20 else "")
            raise KeyError(f"unknown task id {task_id!r} in suite {self.name!r}; valid: {shown}")
        return self.tasks[task_id]

    def subset(self, name: str, task_ids, info: dict | None = None) -> "TaskSuite":
        """A new suite ``name`` of the given tasks, re-numbered ``name/0000``... in the given
        order; ``info["source_ids"]`` keeps the ids they had here."""
        task_ids = list(task_ids)
        tasks = {f"{name}/{k:04d}": self.get(t) for k, t in enumerate(task_ids)}
        return TaskSuite(name, tasks, {**(info or {}), "source_suite": self.name, "source_ids": task_ids})

    def to_body(self) -> dict:
        """The file's content (without its hash): scenes and arrangements stored once."""
        scenes, scene_index = [], {}
        arrangements, arrangement_index = [], {}
        rows = []
        for task_id, task in self.tasks.items():
            d = task.to_dict()
            scene = {k: d.pop(k) for k in SCENE_KEYS}
            key = canonical_json(scene)
            if key not in scene_index:
                scene_index[key] = len(scenes)
                scenes.append(scene)
            target = d.pop("target_index")
            d["scene"] = scene_index[key]
            key = canonical_json(d)
            if key not in arrangement_index:
                arrangement_index[key] = len(arrangements)
                arrangements.append(d)
            rows.append([task_id, arrangement_index[key], target])
        return {
            "format": SUITE_FORMAT, "version": SUITE_VERSION, "name": self.name, "info": self.info,
            "scenes": scenes, "arrangements": arrangements, "tasks": rows,
        }

    def save(self, path) -> None:
        """Write the suite (packed when ``path`` ends in .suite.xz, gzip when in .gz, else plain
        JSON; byte-identical for equal suites)."""
        body = self.to_body()
        body["sha256"] = sha256_bytes(canonical_json(body).encode())
        data = canonical_json(body).encode()
        if str(path).endswith(suite_packed.SUFFIX):
            data = suite_packed.pack(data, sha256_bytes(_gzip_bytes(data)))
        elif str(path).endswith(".gz"):
            data = _gzip_bytes(data)
        atomic_write_bytes(path, data)


def _gzip_bytes(text: bytes) -> bytes:
    return gzip.compress(text, compresslevel=9, mtime=0)


def suite_path(name_or_path) -> Path:
    """The file of a shipped suite name (``test``, ``val``, ``smoke``) or an existing path."""
    path = Path(name_or_path)
    if path.suffix in (".json", ".gz", ".xz") or path.exists():
        if not path.exists():
            raise FileNotFoundError(f"task suite file {path} does not exist")
        return path
    shipped = shipped_suite_file(str(name_or_path))
    if shipped is None:
        raise ValueError(f"unknown task suite {str(name_or_path)!r}; valid: {', '.join(shipped_suites()) or '(none shipped)'}"
                         " or the path of a suite file")
    return shipped


def suite_text(raw: bytes, path) -> bytes:
    """A suite file's JSON text, whichever its form (packed, gzip, plain); ValueError if damaged."""
    if raw[:6] == _XZ_MAGIC:
        try:
            return suite_packed.unpack(raw, "its packed form")[0]
        except ValueError as error:
            raise ValueError(f"task suite {path} is corrupt: {error}") from None
    if raw[:2] == _GZIP_MAGIC:
        try:
            return gzip.decompress(raw)
        except (OSError, EOFError) as error:
            raise ValueError(f"task suite {path} is corrupt: {error}") from None
    return raw


def suite_file_sha256(path) -> str:
    """The identity a run records of the suite file ``path`` (``source_sha256``): the sha256 of
    its bytes, and for a packed suite the sha256 of its ``.json.gz`` form, which its header
    carries, so that a suite is one suite in either form."""
    raw = Path(path).read_bytes()
    if raw[:6] == _XZ_MAGIC:
        return suite_packed.header(raw, f"task suite {path}")["json_gz_sha256"]
    return sha256_bytes(raw)


def load_suite(name_or_path) -> TaskSuite:
    """Load a suite by shipped name or path; a corrupt, tampered or stale file raises ValueError.

    A process reads a file once (a train-suite load is ~2 s: unpacking, the sha256 check and
    ~6,000 tasks built): later loads of the same file, unchanged (path, size, mtime), share its
    tasks (plain data, never changed in place) in a suite object of their own."""
    path = suite_path(name_or_path)
    stat = path.stat()
    loaded = _load_suite_file(str(path.resolve()), stat.st_size, stat.st_mtime_ns)
    return TaskSuite(name=loaded.name, tasks=dict(loaded.tasks), info=dict(loaded.info))


@functools.lru_cache(maxsize=8)  # (a few suites a process: train, val, test, a file of one's own)
def _load_suite_file(path_text: str, size: int, mtime_ns: int) -> TaskSuite:
    path = Path(path_text)
    raw = suite_text(path.read_bytes(), path)
    try:
        body = json.loads(raw)
    except (json.JSONDecodeError, UnicodeDecodeError) as error:
        raise ValueError(f"task suite {path} is corrupt: not JSON ({error})") from None
    if not isinstance(body, dict) or body.get("format") != SUITE_FORMAT:
        raise ValueError(f"{path} is not a {SUITE_FORMAT} file")
    if body.get("version") != SUITE_VERSION:
        raise ValueError(f"{path} is a version {body.get('version')!r} task suite; this install reads version "
                         f"{SUITE_VERSION!r}: regenerate it (scripts/build/build_suite.py)")
    stored = body.pop("sha256", None)
    if stored != sha256_bytes(canonical_json(body).encode()):
        raise ValueError(f"task suite {path} is corrupt: its content does not match its sha256")
    return suite_from_body(body)


def suite_from_body(body: dict) -> TaskSuite:
    scenes = body["scenes"]
    tasks = {}
    for task_id, arrangement, target in body["tasks"]:
        d = dict(body["arrangements"][arrangement])
        d.update(scenes[d.pop("scene")])
        d["target_index"] = target
        tasks[task_id] = TaskSpec.from_dict(d)
    return TaskSuite(name=body["name"], tasks=tasks, info=body.get("info", {}))

"""Task suite files: a named, versioned, hashed set of tasks that envs look up by id.

Filtering tasks into the fixed FetchBench test suite is a later stage; this module is
the file format and the lookup the env uses for ``reset(options={"task_id": ...})``.

File (JSON): ``{"format": "fetchbench-task-suite", "version": "1", "name": ...,
"tasks": {task_id: TaskSpec dict, ...}, "sha256": <hash of the canonical JSON of the
rest>}``. A file whose hash does not match its content is rejected.
"""
from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path

from ..utils.io import atomic_write_text, canonical_json, sha256_bytes
from .spec import TaskSpec

SUITE_FORMAT = "fetchbench-task-suite"
SUITE_VERSION = "1"


@dataclass(frozen=True)
class TaskSuite:
    name: str
    tasks: dict[str, TaskSpec]

    def get(self, task_id: str) -> TaskSpec:
        if task_id not in self.tasks:
            ids = sorted(self.tasks)
            shown = ", ".join(ids[:20]) + (f", ... ({len(ids)} in all)" if len(ids) > 20 else "")
            raise KeyError(f"unknown task id {task_id!r} in suite {self.name!r}; valid: {shown}")
        return self.tasks[task_id]

    def _body(self) -> dict:
        return {
            "format": SUITE_FORMAT,
            "version": SUITE_VERSION,
            "name": self.name,
            "tasks": {k: self.tasks[k].to_dict() for k in sorted(self.tasks)},
        }

    def save(self, path) -> None:
        body = self._body()
        body["sha256"] = sha256_bytes(canonical_json(body).encode())
        atomic_write_text(path, canonical_json(body))


def load_suite(path) -> TaskSuite:
    path = Path(path)
    if not path.exists():
        raise FileNotFoundError(f"task suite file {path} does not exist")
    body = json.loads(path.read_text())
    if body.get("format") != SUITE_FORMAT or body.get("version") != SUITE_VERSION:
        raise ValueError(f"{path} is not a version {SUITE_VERSION} {SUITE_FORMAT} file")
    stored = body.pop("sha256", None)
    if stored != sha256_bytes(canonical_json(body).encode()):
        raise ValueError(f"task suite {path} is corrupt: its content does not match its sha256")
    return TaskSuite(name=body["name"], tasks={k: TaskSpec.from_dict(v) for k, v in body["tasks"].items()})

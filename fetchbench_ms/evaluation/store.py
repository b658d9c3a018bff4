"""The results store: a directory with ``run.json`` (what was run) and ``results.jsonl``
(one JSON line per finished task, appended atomically as tasks finish, in any order).

Resuming: a task whose id has a line is finished and is skipped on the next run. A kill
at any moment leaves at most an unterminated last line (a write cut short); it is
dropped on the next open, so no record is lost or doubled. The manifest pins the method,
the task source and its content hash: resuming into a directory of another run is an
error instead of a silent mix.
"""
from __future__ import annotations

import gzip
import json
import os
from dataclasses import dataclass
from pathlib import Path

from ..utils.io import append_jsonl_atomic, atomic_write_text, canonical_json
from ..utils.packed import unxz_bytes

RESULTS_FILE = "results.jsonl"
PACKED_RESULTS_FILE = "results.jsonl.xz"  # a packed run (results/runs/<name>/, read-only)
#: The earlier form of a packed run's records (gzip), read as well.
LEGACY_PACKED_RESULTS_FILE = "results.jsonl.gz"
MANIFEST_FILE = "run.json"
SUMMARY_FILE = "summary.json"
VIDEO_DIR = "videos"  # <task id>.gif of failed tasks, when recorded
STORE_FORMAT = "fetchbench-results"
STORE_VERSION = "1"


class RunMismatchError(ValueError):
    """The results directory holds another run (method, suite content or options differ)."""


def read_packed_records(path: Path) -> bytes:
    """The JSON lines of a packed run's records file (xz, or the earlier gzip)."""
    data = path.read_bytes()
    return unxz_bytes(data, path) if path.name == PACKED_RESULTS_FILE else gzip.decompress(data)


@dataclass
class ResultsStore:
    root: Path

    @property
    def results_path(self) -> Path:
        return self.root / RESULTS_FILE

    @property
    def manifest_path(self) -> Path:
        return self.root / MANIFEST_FILE

    # ----------------------------------------------------------------- manifest
    def manifest(self) -> dict:
        if not self.manifest_path.exists():
            raise FileNotFoundError(f"{self.root} is not a results directory (no {MANIFEST_FILE}); "
                                    f"make one with `fetchbench eval ... --out {self.root}`")
        return json.loads(self.manifest_path.read_text())

    def holds_records(self) -> bool:
        """Whether any task's record was written (a manifest alone, from a run that stopped
        before its first task, is not a run)."""
        if self.packed_records_file() is not None:
            return True
        return self.results_path.exists() and b"\n" in self.results_path.read_bytes()

    def open_run(self, manifest: dict) -> None:
        """Create the directory for a run, or check that it holds the same run (a directory
        with a manifest and no records takes the new run's manifest)."""
        manifest = {"format": STORE_FORMAT, "version": STORE_VERSION, **manifest}
        if self.manifest_path.exists() and self.holds_records():
            old = self.manifest()
            # A suite is identified by its content (the same file may be named by another path).
            source = "source_sha256" if manifest.get("source_sha256") else "source"
            keys = ("format", "version", "method", source, "method_options")
            diff = [k for k in keys if old.get(k) != manifest.get(k)]
            if diff:
                detail = "; ".join(f"{k}: {old.get(k)!r} there, {manifest.get(k)!r} now" for k in diff)
                raise RunMismatchError(f"{self.root} holds results of another run ({detail}); use another --out")
        else:
            atomic_write_text(self.manifest_path, json.dumps(manifest, indent=1, sort_keys=True) + "\n")
        self.repair()

    # ----------------------------------------------------------------- records
    def repair(self) -> None:
        """Drop an unterminated last line (the append of a killed run, cut short)."""
        path = self.results_path
        if not path.exists():
            return
        with open(path, "rb+") as f:
            data = f.read()
            if data and not data.endswith(b"\n"):
                f.truncate(data.rfind(b"\n") + 1)
                f.flush()
                os.fsync(f.fileno())

    def packed_records_file(self) -> Path | None:
        """The records of a packed run: ``results.jsonl.xz``, or the earlier ``.gz``; None if neither."""
        return next((p for p in (self.root / PACKED_RESULTS_FILE, self.root / LEGACY_PACKED_RESULTS_FILE)
                     if p.exists()), None)

    def records(self) -> list[dict]:
        """Every finished task's record (the last line of a task id wins), in file order."""
        path = self.results_path
        if not path.exists() and self.packed_records_file() is not None:
            path = self.packed_records_file()
            data = read_packed_records(path)
        elif not path.exists():
            if not self.manifest_path.exists():
                self.manifest()  # raises: not a results directory
            return []
        else:
            data = path.read_bytes()
        by_id: dict[str, dict] = {}
        lines = data.split(b"\n")
        complete = lines[:-1]  # the part after the last newline is an append cut short
        for n, line in enumerate(complete, 1):
            if not line.strip():
                continue
            try:
                record = json.loads(line)
            except json.JSONDecodeError as error:
                raise ValueError(f"{path}:{n} is not a JSON line ({error}); "
                                 f"remove that line to resume") from error
            by_id.pop(record["task_id"], None)
            by_id[record["task_id"]] = record
        return list(by_id.values())

    def append(self, record: dict) -> None:
        append_jsonl_atomic(self.results_path, record)

    def write_summary(self, summary: dict) -> None:
        atomic_write_text(self.root / SUMMARY_FILE, canonical_json(summary) + "\n")

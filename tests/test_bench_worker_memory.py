"""scripts/bench/bench_worker_memory.py: its options are checked before any task runs, and its
live-memory report charges each live CUDA block to the package line that allocated it."""
import importlib.util
import subprocess
import sys
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SCRIPT = ROOT / "scripts/bench/bench_worker_memory.py"
spec = importlib.util.spec_from_file_location("bench_worker_memory", SCRIPT)
bench = importlib.util.module_from_spec(spec)
spec.loader.exec_module(bench)


def _run(*args):
    return subprocess.run([sys.executable, str(SCRIPT), "--suite", "smoke", "--tasks", "0:1", *args],
                          capture_output=True, text=True, cwd=ROOT, timeout=300)


def test_bad_options_get_one_line_naming_the_choices_before_any_task():
    out = _run("--planner-option", "trajopt_loop=graph", "--config", "graph_cash=1")
    assert out.returncode != 0 and "unknown TrajoptConfig field 'graph_cash'; valid:" in out.stderr
    assert "graph_cache" in out.stderr and "rss" not in out.stdout  # no task ran
    out = _run("--planner-option", "trajopt_loop=fast")
    assert out.returncode == 2 and "trajopt_loop" in out.stderr and "graph" in out.stderr
    out = _run("--live-tensors", "3")
    assert out.returncode == 2 and "--live-tensors needs a CUDA device" in out.stderr
    out = _run("--live-tensors", "-1")
    assert out.returncode == 2 and "a number of lines >= 0, not -1" in out.stderr


def test_live_memory_is_charged_to_the_innermost_package_frame(monkeypatch):
    import torch

    def frame(path, line, name):
        return {"filename": path, "line": line, "name": name}

    pkg = "/x/site/fetchbench_ms/planning/"
    inner, outer = frame(pkg + "trajopt.py", 420, "_optimise"), frame(pkg + "sense.py", 9, "plan")
    torch_frame = frame("/x/site/torch/functional.py", 7, "einsum")
    snapshot = {"segments": [
        {"blocks": [{"size": 64 << 20, "state": "active_allocated", "frames": [torch_frame, inner, outer]},
                    {"size": 32 << 20, "state": "inactive", "frames": [inner]},  # free: not charged
                    {"size": 2 << 20, "state": "active_allocated", "frames": [outer]}]},
        {"blocks": [{"size": 64 << 20, "state": "active_allocated", "frames": [inner]},
                    {"size": 1 << 20, "state": "active_allocated", "frames": [torch_frame]}]}]}
    monkeypatch.setattr(torch.cuda.memory, "_snapshot", lambda: snapshot)
    lines = bench.live_tensor_lines(2)
    assert len(lines) == 2
    assert lines[0].split() == ["128.0", "MB", "2", "planning/trajopt.py:420", "_optimise"]
    assert lines[1].split() == ["2.0", "MB", "1", "planning/sense.py:9", "plan"]
    assert "(no fetchbench_ms frame)" in bench.live_tensor_lines(3)[2]


def test_show_reprints_a_records_first_last_and_largest_figures(tmp_path, capsys):
    import json

    def row(rss, allocated, loops):
        return {"task_id": "val/0000", "success": True, "rss_mb": rss, "cuda_allocated_mb": allocated,
                "cuda_reserved_mb": 2 * allocated, "graph_loops": loops, "caches": {"a.cache": 3}}

    rows = [row(100.0, 160.2, {"cached": 1, "new": 1, "evicted": 0}),
            row(180.0, 224.0, {"cached": 1, "new": 2, "evicted": 1}),
            row(150.0, 160.2, {"cached": 1, "new": 3, "evicted": 2})]
    record = {"method": "ga-mesh-trajopt", "pipeline": "paper", "suite": "val", "tasks": "0:3",
              "planner_options": {"trajopt_loop": "graph"}, "config": ["graph_cache=1"], "device": "cuda",
              "cache_bounds": {"a.cache": 8}, "per_task": rows}
    path = tmp_path / "r.json"
    path.write_text(json.dumps(record))
    assert bench.show([str(path)]) == 0
    out = capsys.readouterr().out
    assert "ga-mesh-trajopt (paper trajopt_loop=graph --config graph_cache=1), val 0:3: 3 tasks on cuda" in out
    assert "RSS after the first task 100 MB, after the last 150 MB, largest 180 MB" in out
    assert "cuda_allocated_mb: first 160.2, last 160.2, largest 224.0" in out
    assert "captured loops at the end: cached 1, new 3, evicted 2" in out and "a.cache 3/8" in out
    (tmp_path / "bad.json").write_text("{}")
    assert bench.show([str(tmp_path / "bad.json")]) == 1
    assert "not a record of --json" in capsys.readouterr().err

"""scripts/bench/gpu_memory.py: the summary of a long run's GPU memory log (docs/evaluation.md,
"Throughput") reads the first and last samples with every worker past its start-up."""
import gzip
import importlib.util
import json
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
spec = importlib.util.spec_from_file_location("gpu_memory", ROOT / "scripts/bench/gpu_memory.py")
gpu_memory = importlib.util.module_from_spec(spec)
spec.loader.exec_module(gpu_memory)


def _sample(t, gpu_mib, procs, rss):
    lines = [f"T {t}"] + [f"{i}, {m} MiB, 99 %" for i, m in enumerate(gpu_mib)]
    lines += [f"GPU-{'ab'[g]}, {pid}, {m} MiB" for g, pid, m in procs]
    return lines + [f"RSS_MB {rss} NPROC {len(procs) + 1}"]


def _log(tmp_path, gz=False):
    lines = ["# a comment: the run's command"]
    lines += _sample(0, [4, 4], [], 50)                                    # before the workers
    lines += _sample(20, [900, 800], [(0, 1, 30), (0, 2, 900), (1, 3, 800)][:2], 900)  # one missing
    lines += _sample(40, [1000, 900], [(0, 1, 30), (0, 2, 900), (1, 3, 800)], 1000)    # 1 starting up
    lines += _sample(60, [2000, 1000], [(0, 1, 1000), (0, 2, 900), (1, 3, 800)], 2000)  # all up: first
    lines += _sample(80, [2100, 1050], [(0, 1, 1100), (0, 2, 950), (1, 3, 850)], 2100)  # last
    lines += _sample(100, [4, 500], [(1, 3, 500)], 600)                    # one half done
    path = tmp_path / ("smi.log.gz" if gz else "smi.log")
    text = "\n".join(lines) + "\n"
    if gz:
        with gzip.open(path, "wt") as f:
            f.write(text)
    else:
        path.write_text(text)
    return path


@pytest.mark.parametrize("gz", [False, True])
def test_summary_takes_the_first_and_last_samples_with_every_worker_up(tmp_path, gz):
    s = gpu_memory.summary(gpu_memory.read_samples(str(_log(tmp_path, gz))))
    assert (s["samples"], s["processes"], s["seconds"]) == (2, 3, 20)
    assert s["gpus"]["0"]["first_mib"] == 2000 and s["gpus"]["0"]["last_mib"] == 2100
    assert s["gpus"]["0"]["change"] == pytest.approx(0.05)
    assert s["gpus"]["1"]["peak_mib"] == 1050
    assert s["per_process_mib"]["first"] == {"min": 800, "median": 900, "max": 1000}
    assert s["host_rss_mb"] == {"first": 2000.0, "last": 2100.0}


def test_cli_prints_and_writes_the_summary_and_fails_on_an_empty_log(tmp_path, capsys):
    out = tmp_path / "s.json"
    assert gpu_memory.main([str(_log(tmp_path)), "--json", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "GPU 0: 2.0 GiB first, 2.1 GiB last (+5.0 %)" in printed
    assert json.loads(out.read_text())["processes"] == 3
    empty = tmp_path / "empty.log"
    empty.write_text("# nothing sampled\n")
    assert gpu_memory.main([str(empty)]) == 1
    assert "no samples" in capsys.readouterr().err


def test_window_medians_smooth_a_swinging_series(tmp_path):
    """The first and last ``window`` seconds' medians: one sample's swing (a worker holding a
    task's transient tensors at that moment) does not decide the change."""
    lines = []
    procs = [(0, 1, 1000), (0, 2, 1000)]
    for t, mib in enumerate([1000, 1400, 1000, 1000, 1000, 1000, 1100, 1000]):  # a swing at each end
        lines += _sample(20 * t, [mib], procs, 100)
    path = tmp_path / "swing.log"
    path.write_text("\n".join(lines) + "\n")
    s = gpu_memory.summary(gpu_memory.read_samples(str(path)), window=40)
    g = s["gpus"]["0"]
    assert (g["first_mib"], g["last_mib"]) == (1000, 1000) and g["change"] == 0
    assert (g["first_window_mib"], g["last_window_mib"]) == (1000, 1000)  # 3 samples each, medians
    s = gpu_memory.summary(gpu_memory.read_samples(str(path)), window=20)  # 2 samples: their mean
    assert s["gpus"]["0"]["first_window_mib"] == 1200 and s["gpus"]["0"]["last_window_mib"] == 1050
    assert s["gpus"]["0"]["window_change"] == pytest.approx(-0.125)
    assert gpu_memory.main([str(path), "--window", "-1"]) == 2


def test_samples_where_every_worker_holds_only_its_context_are_start_up(tmp_path):
    """At a run's start every worker may hold only its CUDA context (~40 MiB), so each holds a
    quarter of the sample's own median: a worker counts as started from a quarter of the
    run's median per process, and such samples are not the run's first."""
    lines = []
    lines += _sample(0, [80, 40], [(0, 1, 40), (0, 2, 40), (1, 3, 40)], 100)        # contexts only
    lines += _sample(20, [1040, 40], [(0, 1, 1000), (0, 2, 40), (1, 3, 40)], 1000)  # one started
    lines += _sample(40, [1900, 800], [(0, 1, 1000), (0, 2, 900), (1, 3, 800)], 2000)  # all up: first
    lines += _sample(60, [2000, 850], [(0, 1, 1050), (0, 2, 950), (1, 3, 850)], 2100)
    path = tmp_path / "start.log"
    path.write_text("\n".join(lines) + "\n")
    s = gpu_memory.summary(gpu_memory.read_samples(str(path)))
    assert (s["samples"], s["seconds"]) == (2, 20)
    assert s["gpus"]["0"]["first_mib"] == 1900 and s["per_process_mib"]["first"]["min"] == 800

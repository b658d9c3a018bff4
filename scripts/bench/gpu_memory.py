"""GPU and host memory over a long evaluation, from a log of ``scripts/bench/log_gpu_memory.sh``.

Prints, for the samples taken while the run's workers were all up (the samples with the most
processes on the GPUs, from the first in which each of them holds at least a quarter of the
run's median per process: a worker starting up holds only its CUDA context), each GPU's
memory used at the first and the last of them and the change, the medians of the samples
within ``--window`` seconds (60) of both ends and their change (a sample swings with what
the workers' tasks hold at that moment), the per-process memory (min / median / max over the
workers) at both ends, and the host's resident memory of all python3 processes; with
``--json`` the same as one object:

    python scripts/bench/gpu_memory.py results/logs/ga-mesh-trajopt-paper-test6000-gpu-memory.log.gz

A log may be gzipped; lines starting with ``#`` are comments (the run's command and times).
"""
from __future__ import annotations

import argparse
import gzip
import json
import statistics
import sys


def read_samples(path: str) -> list[dict]:
    """The log's samples in order: ``t`` (unix s), ``gpus`` {index: MiB}, ``util`` {index: %},
    ``procs`` [(gpu uuid, pid, MiB)], ``rss_mb`` and ``n_python`` when logged."""
    opener = gzip.open if path.endswith(".gz") else open
    samples: list[dict] = []
    with opener(path, "rt") as f:
        for raw in f:
            line = raw.strip()
            if not line or line.startswith("#"):
                continue
            if line.startswith("T "):
                samples.append({"t": int(line[2:]), "gpus": {}, "util": {}, "procs": []})
            elif not samples:
                continue
            elif line.startswith("RSS_MB"):
                parts = line.split()
                samples[-1]["rss_mb"], samples[-1]["n_python"] = float(parts[1]), int(parts[3])
            elif line.startswith("GPU-"):
                uuid, pid, mem = (x.strip() for x in line.split(","))
                samples[-1]["procs"].append((uuid, int(pid), int(mem.split()[0])))
            elif line.count(",") == 2 and line.split(",")[0].strip().isdigit():
                index, mem, util = (x.strip() for x in line.split(","))
                samples[-1]["gpus"][index] = int(mem.split()[0])
                samples[-1]["util"][index] = int(util.split()[0])
    return samples


def summary(samples: list[dict], window: float = 60.0) -> dict:
    """First and last of the samples with every worker up (the most GPU processes, each past
    its start-up); per GPU also the median of those samples within ``window`` seconds of the
    first and of the last (a single sample swings with the tasks' transient tensors)."""
    if not samples:
        raise ValueError("no samples in the log")
    most = max(len(s["procs"]) for s in samples)
    if most == 0:
        raise ValueError("no process ever held GPU memory in the log")
    full = [s for s in samples if len(s["procs"]) == most]

    def per_process(s):
        mib = [m for _, _, m in s["procs"]]
        return {"min": min(mib), "median": statistics.median(mib), "max": max(mib)}

    # A worker past its start-up holds more than its CUDA context: at least a quarter of the
    # run's median per-process memory (not the sample's own median: in the first samples every
    # worker may hold only its context).
    typical = statistics.median(m for s in full for _, _, m in s["procs"])

    def started(s):
        return per_process(s)["min"] >= typical / 4

    full = full[next((i for i, s in enumerate(full) if started(s)), 0):]
    first, last = full[0], full[-1]

    gpus = {}
    for index in sorted(first["gpus"]):
        a, b = first["gpus"][index], last["gpus"].get(index, float("nan"))
        peak = max(s["gpus"].get(index, 0) for s in full)
        head = statistics.median(s["gpus"].get(index, 0) for s in full if s["t"] <= first["t"] + window)
        tail = statistics.median(s["gpus"].get(index, 0) for s in full if s["t"] >= last["t"] - window)
        gpus[index] = {"first_mib": a, "last_mib": b, "peak_mib": peak, "change": (b - a) / a if a else None,
                       "first_window_mib": head, "last_window_mib": tail,
                       "window_change": (tail - head) / head if head else None,
                       "util_median": statistics.median(s["util"].get(index, 0) for s in full)}
    return {"samples": len(full), "processes": most, "seconds": last["t"] - first["t"], "window_s": window,
            "gpus": gpus,
            "per_process_mib": {"first": per_process(first), "last": per_process(last)},
            "host_rss_mb": {"first": first.get("rss_mb"), "last": last.get("rss_mb")}}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("log", help="a log of scripts/bench/log_gpu_memory.sh (.gz or plain)")
    ap.add_argument("--json", help="also write the summary to this file")
    ap.add_argument("--window", type=float, default=60.0, metavar="SECONDS",
                    help="the medians over the first and last SECONDS of the samples (default 60)")
    args = ap.parse_args(argv)
    if not args.window > 0:
        print(f"gpu_memory: --window must be > 0 seconds, not {args.window}", file=sys.stderr)
        return 2
    try:
        s = summary(read_samples(args.log), args.window)
    except (OSError, ValueError) as e:
        print(f"gpu_memory: {args.log}: {e}", file=sys.stderr)
        return 1
    print(f"{s['samples']} samples over {s['seconds']} s with {s['processes']} processes on the GPUs")
    for index, g in s["gpus"].items():
        change = "-" if g["change"] is None else f"{100 * g['change']:+.1f} %"
        print(f"GPU {index}: {g['first_mib'] / 1024:.1f} GiB first, {g['last_mib'] / 1024:.1f} GiB last "
              f"({change}), peak {g['peak_mib'] / 1024:.1f} GiB, median utilisation {g['util_median']:.0f} %")
        wchange = "-" if g["window_change"] is None else f"{100 * g['window_change']:+.1f} %"
        print(f"  median of the first and last {s['window_s']:g} s: {g['first_window_mib'] / 1024:.1f} and "
              f"{g['last_window_mib'] / 1024:.1f} GiB ({wchange})")
    for end in ("first", "last"):
        p = s["per_process_mib"][end]
        print(f"per process, {end}: min {p['min']} / median {p['median']:.0f} / max {p['max']} MiB")
    rss = s["host_rss_mb"]
    if rss["first"] is not None:
        print(f"host resident memory of the python processes: {rss['first'] / 1024:.1f} GiB first, "
              f"{rss['last'] / 1024:.1f} GiB last")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(s, f, indent=1)
    return 0


if __name__ == "__main__":
    sys.exit(main())

"""What the round commands share (``scripts/imitation/imitation_round.py``, ``scripts/grasp_round.py``): each
round takes the next slice of a suite after the last recorded round's, logs to its work folder,
and the rounds stop at a plateau of their val figure."""
from __future__ import annotations

import math
import time
from pathlib import Path
from typing import Callable


def next_tasks(record: dict, count: int) -> tuple[int, int]:
    """The ``count`` tasks after the last recorded round's slice (``rounds[-1]["tasks"]``)."""
    start = record["rounds"][-1]["tasks"][1] if record["rounds"] else 0
    return start, start + count


def parse_slice(text: str, flag: str, example: str) -> tuple[int, int]:
    """``START:END`` with 0 <= START < END, or a one-line SystemExit naming ``flag``."""
    try:
        start, end = (int(v) for v in text.split(":"))
    except ValueError:
        raise SystemExit(f"error: {flag} takes START:END (e.g. {example}), got {text!r}") from None
    if not 0 <= start < end:
        raise SystemExit(f"error: {flag} {text}: START must be >= 0 and below END")
    return start, end


def no_gain_in_two(scores: list[float]) -> bool:
    """A plateau: no round's score above the best before it, two rounds running."""
    best, since = -math.inf, 0
    for score in scores:
        best, since = (score, 0) if score > best else (best, since + 1)
    return since >= 2


def round_log(path: Path):
    """A function that prints a time-stamped line and appends it to ``path``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    log_file = open(path, "a")

    def log(message: str) -> None:
        line = f"[{time.strftime('%H:%M:%S')}] {message}"
        print(line, flush=True)
        log_file.write(line + "\n")
        log_file.flush()

    return log


def answer_report(args, record: dict, costs: Callable[[], str], status: Callable[[dict], str],
                  plot: Callable[[dict, Path], None]) -> bool:
    """Answer ``--costs``, ``--status`` or ``--plot`` (the commands' read-only modes) from the
    record; False when none was asked for and a round is to run."""
    if args.costs:
        print(costs())
    elif args.status:
        print(status(record))
    elif args.plot:
        if not record["rounds"]:
            raise SystemExit(f"error: {args.record / 'rounds.json'}: no round recorded, nothing to plot")
        plot(record, args.plot)
    else:
        return False
    return True

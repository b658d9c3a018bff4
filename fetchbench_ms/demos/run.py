"""ManiSkill's motion-planning generator, for FetchBench (the same flags):

    python -m fetchbench_ms.demos.run -e FetchBench-v0 -n 100 --only-count-success \\
        --record-dir demos --traj-name train --num-procs 16 [--task-suite train] [--save-video]

is ``fetchbench demos run`` (``fetchbench demos run --help`` lists every flag).
"""
from __future__ import annotations

import sys


def main(argv=None) -> int:
    from ..cli import main as fetchbench_main

    return fetchbench_main(["demos", "run", *(sys.argv[1:] if argv is None else argv)])


if __name__ == "__main__":
    sys.exit(main())

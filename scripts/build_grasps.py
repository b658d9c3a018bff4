"""Rebuild the grasp library (same as `fetchbench grasps build`; resumes from finished shards).

    python scripts/build_grasps.py --workers 16 --deadline 540
"""
import sys

from fetchbench_ms.cli import main

if __name__ == "__main__":
    sys.exit(main(["grasps", "build", *sys.argv[1:]]))

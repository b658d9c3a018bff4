"""The tracked tree stays small (docs/architecture.md, "Rules for contributors"): a checkout is
copied whole to the machines that run the benchmark, so every tracked byte costs everyone.
What is generated is regenerated, not tracked; old versions of assets live in git history."""
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
LIMIT_MB = 50           # fails above this
LARGEST_FILE_MB = 10    # one file this large is an asset to split, compress or regenerate


def _tracked_sizes() -> dict[str, int]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    sizes = {}
    for rel in filter(None, out.decode().split("\0")):
        path = ROOT / rel
        if path.is_file() and not path.is_symlink():
            sizes[rel] = path.stat().st_size
    return sizes


# Known today: 57.8 MB, of which assets/checkpoints 26.3 MB (their bytes are what the shipped
# evaluation records name). Strict: once the tree is under the limit this marker fails the
# run, so it is removed in the same change.
@pytest.mark.xfail(strict=True, reason="the shipped checkpoints (26.3 MB) keep the tree above 50 MB until they move")
def test_tracked_tree_is_at_most_50_mb():
    sizes = _tracked_sizes()
    total = sum(sizes.values())
    largest = ", ".join(f"{rel} {size / 1e6:.1f} MB" for rel, size in sorted(sizes.items(), key=lambda kv: -kv[1])[:5])
    assert total <= LIMIT_MB * 1e6, (f"the tracked tree is {total / 1e6:.1f} MB, more than {LIMIT_MB} MB; "
                                     f"the largest files: {largest}")


def test_no_tracked_file_is_huge():
    big = {rel: size for rel, size in _tracked_sizes().items() if size > LARGEST_FILE_MB * 1e6}
    assert not big, f"tracked files over {LARGEST_FILE_MB} MB: {big}"


def test_the_demo_sample_is_at_most_2_mb():
    """The shipped demo sample (20 trajectories) is written with HDF5's latest file format, whose
    metadata is a fraction of the default's (0.85 MB against 2.07 MB for the same datasets)."""
    sample = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
    assert sample.stat().st_size <= 2e6, f"{sample.relative_to(ROOT)}: {sample.stat().st_size / 1e6:.2f} MB"

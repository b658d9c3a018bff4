"""The tracked tree stays small (docs/architecture.md, "Rules for contributors"): a checkout is
copied whole to the machines that run the benchmark, so every tracked byte costs everyone.
What is generated is regenerated, not tracked; old versions of assets live in git history."""
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
TOTAL_LIMIT_MB = 50
LARGEST_FILE_MB = 7     # one file this large is an asset to split, compress or regenerate


def _tracked_sizes() -> dict[str, int]:
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    sizes = {}
    for rel in filter(None, out.decode().split("\0")):
        path = ROOT / rel
        if path.is_file() and not path.is_symlink():
            sizes[rel] = path.stat().st_size
    return sizes


# The shipped checkpoints (21.3 MB packed: four imitation policies, our CGN weights, the
# collision net) are the bytes the shipped evaluation records name; they are bounded apart
# (a round's checkpoint replaces one of its kind's size), the rest of the tree (28.1 MB: the
# rounds' records and round commands) is held to what it is plus a little room, and the whole to
# TOTAL_LIMIT_MB. Every bound fails the run when crossed: growth has to be paid for by
# removing something, or by room moved from one part to the other under the same total.
# (The large assets are packed losslessly: fetchbench_ms/utils/packed.py.)
CHECKPOINTS_LIMIT_MB = 21.7
REST_LIMIT_MB = 28.3


def _largest(sizes: dict[str, int]) -> str:
    return ", ".join(f"{rel} {size / 1e6:.1f} MB" for rel, size in sorted(sizes.items(), key=lambda kv: -kv[1])[:5])


def test_tracked_tree_stays_within_its_budget():
    sizes = _tracked_sizes()
    checkpoints = {rel: n for rel, n in sizes.items() if rel.startswith("assets/checkpoints/")}
    rest = {rel: n for rel, n in sizes.items() if rel not in checkpoints}
    total, ck, other = sum(sizes.values()), sum(checkpoints.values()), sum(rest.values())
    assert ck <= CHECKPOINTS_LIMIT_MB * 1e6, (f"assets/checkpoints is {ck / 1e6:.1f} MB, more than "
                                              f"{CHECKPOINTS_LIMIT_MB} MB: {_largest(checkpoints)}")
    assert other <= REST_LIMIT_MB * 1e6, (f"the tracked tree without checkpoints is {other / 1e6:.1f} MB, more "
                                          f"than {REST_LIMIT_MB} MB; the largest files: {_largest(rest)}")
    assert total <= TOTAL_LIMIT_MB * 1e6, f"the tracked tree is {total / 1e6:.1f} MB, more than {TOTAL_LIMIT_MB} MB"


def test_no_tracked_file_is_huge():
    big = {rel: size for rel, size in _tracked_sizes().items() if size > LARGEST_FILE_MB * 1e6}
    assert not big, f"tracked files over {LARGEST_FILE_MB} MB: {big}"


def test_the_demo_sample_is_at_most_2_mb():
    """The shipped demo sample (20 trajectories) is written with HDF5's latest file format, whose
    metadata is a fraction of the default's (0.85 MB against 2.07 MB for the same datasets)."""
    sample = ROOT / "assets/demos/sample/FetchBench-v0/motionplanning/train-sample.h5"
    assert sample.stat().st_size <= 2e6, f"{sample.relative_to(ROOT)}: {sample.stat().st_size / 1e6:.2f} MB"

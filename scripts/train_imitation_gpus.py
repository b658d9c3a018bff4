"""Moved to scripts/imitation/train_imitation_gpus.py; this path forwards to it (shipped records' commands name it)."""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parent / "imitation" / "train_imitation_gpus.py"), run_name="__main__")

"""Moved to scripts/imitation/select_checkpoint.py; this path forwards to it (shipped records' commands name it)."""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parent / "imitation" / "select_checkpoint.py"), run_name="__main__")

"""Moved to scripts/imitation/build_imitation_data.py; this path forwards to it (shipped records' commands name it)."""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parent / "imitation" / "build_imitation_data.py"), run_name="__main__")

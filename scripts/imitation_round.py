"""Moved to scripts/imitation/imitation_round.py; this path forwards to it (shipped records' commands name it)."""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parent / "imitation" / "imitation_round.py"), run_name="__main__")

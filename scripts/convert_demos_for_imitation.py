"""Moved to scripts/imitation/convert_demos_for_imitation.py; this path forwards to it (shipped records' commands name it)."""
import runpy
from pathlib import Path

runpy.run_path(str(Path(__file__).resolve().parent / "imitation" / "convert_demos_for_imitation.py"), run_name="__main__")

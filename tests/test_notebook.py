"""examples/quickstart.ipynb runs as a user runs it: its code cells in order, in one
namespace, in a fresh folder (what `jupyter nbconvert --execute` does with a kernel)."""
from __future__ import annotations

import json
from pathlib import Path

import matplotlib

NOTEBOOK = Path(__file__).resolve().parents[1] / "examples" / "quickstart.ipynb"


def test_quickstart_notebook_runs_and_writes_its_figures(tmp_path, monkeypatch):
    notebook = json.loads(NOTEBOOK.read_text())
    assert notebook["nbformat"] == 4 and all("id" in c for c in notebook["cells"])
    code = [c for c in notebook["cells"] if c["cell_type"] == "code"]
    assert code and all(not c["outputs"] for c in code)  # shipped without outputs: they come from running it
    matplotlib.use("Agg")  # no display in a test; a notebook shows them inline
    monkeypatch.chdir(tmp_path)
    namespace: dict = {"__name__": "__main__"}
    for i, cell in enumerate(code):
        exec(compile("".join(cell["source"]), f"{NOTEBOOK.name}[{i}]", "exec"), namespace)
    for picture in ("quickstart_cloud.png", "quickstart_result.png"):
        assert (tmp_path / picture).stat().st_size > 1000
    assert namespace["record"]["task_id"] == "smoke/0000" and isinstance(namespace["record"]["success"], bool)
    assert len(namespace["clouds"].target) > 0 and len(namespace["clouds"].scene) > len(namespace["clouds"].target)
    lines = (tmp_path / "out" / "quickstart" / "results.jsonl").read_text().splitlines()
    assert [json.loads(line)["task_id"] for line in lines] == ["smoke/0000"]

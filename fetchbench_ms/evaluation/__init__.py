"""Evaluation at scale: the runner (local worker processes or Ray), the results store,
metrics and the HTML report. See docs/results.md."""
from .metrics import format_table, summarize
from .runner import evaluate, open_suite
from .store import ResultsStore

__all__ = ["ResultsStore", "evaluate", "format_table", "open_suite", "summarize"]

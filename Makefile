# The two commands of the README. Both set up what they need first (idempotent).
.PHONY: setup demo test test-slow bench

PY := .venv/bin/python

setup:
	@bash scripts/setup.sh

demo: setup
	@$(PY) -m fetchbench_ms demo

test: setup
	@$(PY) -m pytest -q -n 2 --dist loadfile

test-slow: setup
	@$(PY) -m pytest -q -m slow

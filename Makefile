# The README's two commands are `make demo` and `make test`; both set up what they need
# first (scripts/setup.sh: venv, editable install, software Vulkan if needed; idempotent).
# FETCHBENCH_VENV picks another virtual environment (default .venv). setup installs the
# exact versions in requirements.lock; `make lock` regenerates that file (after changing
# dependencies in pyproject.toml); `make bundle` makes the offline kit of an air-gapped node.
.PHONY: setup demo test test-slow bench gallery lock bundle

VENV ?= $(or $(FETCHBENCH_VENV),.venv)
PY := $(VENV)/bin/python
# Parallel test workers (pytest-xdist); `loadfile` keeps a file's tests on one worker so
# expensive one-off set-ups (the renderer's shader compilation) happen once per file.
TEST_WORKERS ?= 2

setup:
	@FETCHBENCH_VENV=$(VENV) bash scripts/setup.sh

demo: setup
	@$(PY) -m fetchbench_ms demo

test: setup
	@$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile

test-slow: setup
	@$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile -m slow

bench: setup
	@$(PY) scripts/bench/bench_scenes.py

gallery: setup
	@$(PY) scripts/build/make_gallery.py

# Not a dependency of setup: the lock changes only when someone means it to.
lock:
	@bash scripts/maint/lock.sh

# The offline kit of an air-gapped node (docs/offline-install.md): the locked wheels in .whl/
# and the Vulkan/EGL loaders in .gl/; downloads only. BUNDLE_ARGS go to scripts/offline/bundle.py
# (e.g. --python-version 3.11, or a size split: --split-mib 500).
BUNDLE_ARGS ?=
bundle:
	@bash scripts/offline/kit.sh $(BUNDLE_ARGS)

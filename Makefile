# The two set-up commands of the README: `make demo` and `make test`.
#
# They install into a project virtual environment (.venv, created on first use) unless one is already
# active (VIRTUAL_ENV set), so they work on a Debian/Ubuntu system python3 (PEP 668 refuses a plain
# `pip install` there), on pyenv and in CI alike. PYTHON picks the interpreter that creates the venv.
PYTHON ?= python3

ifdef VIRTUAL_ENV
VENV := $(VIRTUAL_ENV)
else
VENV := .venv
endif
BIN := $(VENV)/bin
STAMP := $(VENV)/.safemanip-installed

.PHONY: install system-deps demo test test-fast bench clean-venv

# Mesa's EGL for headless offscreen rendering (MUJOCO_GL=egl). Skipped when already present or not root.
system-deps:
	@if ldconfig -p 2>/dev/null | grep -q libEGL.so.1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1-mesa-dri >/dev/null; \
	else echo "note: install libegl1 and libgl1-mesa-dri for rendering (or run demos with --no-video)"; fi

$(BIN)/python:
	@$(PYTHON) -c 'import sys; sys.exit(0 if sys.version_info >= (3, 11) else "safemanip needs Python 3.11 or newer: make PYTHON=python3.11 ...")'
	@$(PYTHON) -m venv $(VENV) || { echo "could not create $(VENV): on Debian/Ubuntu install the venv module (apt-get install python3-venv), or activate a virtual environment first"; exit 1; }

# reinstalled when the project's dependencies change
$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install -q -e ".[dev]"
	@touch $(STAMP)

install: system-deps $(STAMP)

demo: install
	$(BIN)/safemanip demo

test: install
	$(BIN)/python -m pytest -q

# the suite without the tests marked slow (longer physics, learning and process checks): for local work
test-fast: install
	$(BIN)/python -m pytest -q -m "not slow"

bench: install
	$(BIN)/python benchmarks/env_throughput.py

clean-venv:
	rm -rf .venv

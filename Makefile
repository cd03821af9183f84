# The two set-up commands of the README: `make demo` and `make test`.
PYTHON ?= python3
PIP ?= $(PYTHON) -m pip

.PHONY: install system-deps demo test bench

# Mesa's EGL for headless offscreen rendering (MUJOCO_GL=egl). Skipped when already present or not root.
system-deps:
	@if ldconfig -p 2>/dev/null | grep -q libEGL.so.1; then :; \
	elif [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
		apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq libegl1 libgl1-mesa-dri >/dev/null; \
	else echo "note: install libegl1 and libgl1-mesa-dri for rendering (or run demos with --no-video)"; fi

install: system-deps
	$(PIP) install -q -e ".[dev]"

demo: install
	safemanip demo

test: install
	$(PYTHON) -m pytest -q

bench: install
	$(PYTHON) benchmarks/env_throughput.py

# `make demo` and `make test` do all set-up on a fresh machine (see README).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# torch is pinned so pip takes the CPU wheel, never a multi-GB CUDA build; only tests and training use it.
TORCH ?= torch==2.13.0

.PHONY: demo test lint system-deps clean

$(VENV)/.runtime: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e .
	touch $@

$(VENV)/.dev: $(VENV)/.runtime
	$(PY) -m pip install -q "$(TORCH)"
	$(PY) -m pip install -q -e ".[dev,gstreamer,train]"
	$(PY) -m pip install -q --no-deps MAVProxy
	touch $@

system-deps:
	./scripts/install-system-deps.sh

demo: $(VENV)/.runtime
	$(VENV)/bin/glad-payload demo --out demo-output

test: system-deps $(VENV)/.dev
	@# The GStreamer tests must run, not skip, wherever `make test` is the test command.
	$(PY) -c "import gi; gi.require_version('Gst', '1.0'); from gi.repository import Gst; Gst.init(None)"
	$(PY) -m pytest -q -ra

lint: $(VENV)/.dev
	$(VENV)/bin/ruff check payload tests sitl training bench
	$(VENV)/bin/vermin --target=3.8- --no-tips --violations --eval-annotations payload/

clean:
	rm -rf $(VENV) demo-output

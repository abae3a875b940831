# `make demo` and `make test` do all set-up on a fresh machine (see README).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
# torch is pinned so pip takes the CPU wheel, never a multi-GB CUDA build; only tests and training use it.
TORCH ?= torch==2.13.0
# `make test38`: the runtime on the Xavier NX's Python 3.8 (JetPack 5) with Jetson-like library versions.
# pyenv's python3.8 shim only works where 3.8 is selected, so the interpreter itself is preferred.
PYTHON38 ?= $(firstword $(wildcard $(HOME)/.pyenv/versions/3.8*/bin/python3.8) python3.8)
VENV38 ?= .venv38
PY38 := $(VENV38)/bin/python
CONSTRAINTS38 ?= constraints/jetson-py38.txt

.PHONY: demo test test38 test38-floor lint system-deps clean

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

# No torch, no PyGObject, no MAVProxy: tests that need them skip. setuptools is pinned in the venv and the
# build is not isolated so that it uses that setuptools (75.3, the last for 3.8) instead of fetching the newest.
$(VENV38)/.runtime: pyproject.toml $(CONSTRAINTS38)
	$(PYTHON38) -c "import sys; assert sys.version_info[:2] == (3, 8), sys.version"
	$(PYTHON38) -m venv $(VENV38)
	$(PY38) -m pip install -q -c $(CONSTRAINTS38) --upgrade pip setuptools wheel
	$(PY38) -m pip install -q -c $(CONSTRAINTS38) --no-build-isolation -e . pytest pytest-timeout onnx hypothesis
	touch $@

system-deps:
	./scripts/install-system-deps.sh

demo: $(VENV)/.runtime
	$(VENV)/bin/glad-payload demo --out demo-output

test: system-deps $(VENV)/.dev
	@# The GStreamer tests must run, not skip, wherever `make test` is the test command.
	$(PY) -c "import gi; gi.require_version('Gst', '1.0'); gi.require_version('GstRtspServer', '1.0'); from gi.repository import Gst, GstRtspServer; Gst.init(None)"
	$(PY) -m pytest -q -ra

test38: $(VENV38)/.runtime
	$(PY38) -m pytest -q -ra

# The same on the lowest versions pyproject.toml declares (NumPy 1.21, onnxruntime 1.12, pydantic 2.0, OpenCV 4.5.4).
test38-floor:
	$(MAKE) test38 VENV38=.venv38-floor CONSTRAINTS38=constraints/jetson-py38-floor.txt

lint: $(VENV)/.dev
	$(VENV)/bin/ruff check payload tests sitl training bench
	$(VENV)/bin/vermin --target=3.8- --no-tips --violations --eval-annotations payload/

clean:
	rm -rf $(VENV) $(VENV38) .venv38-floor demo-output

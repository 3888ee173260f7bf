# Silhouette Cloth Fit: every command sets up its own environment first.
#   make demo   - the paper scenario on the built-in lab18 rig: Blender-rendered observations, fit,
#                 tables and overlays under out/
#   make test   - the whole test suite (pure core + Blender layer through the bpy module)
#   make bench  - speed figures (out/bench.json)
#   make paper  - the full paper protocol (Table 1, Fig. 8, Table 2, optimisers; out/paper.json)
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv demo test bench paper extension clean

venv: $(STAMP)

# the development environment: the runtime pins (requirements.txt) + tests and tools (requirements-dev.txt),
# then this package, editable and without dependencies (they are pinned above): .venv/bin/clothfit
$(STAMP): requirements.txt requirements-dev.txt pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "error: $(PYTHON) not found (bpy 4.5 needs Python 3.11); set PYTHON=..."; exit 2; }
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -r requirements-dev.txt
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e .
	touch $(STAMP)

demo: venv
	$(PY) demo_blend/build_demo.py --out out/demo --blend out/demo/demo.blend
	$(PY) -m addon paper --quick --json out/paper_quick.json --out out/paper_quick --only table1 >/dev/null
	@echo "demo done: see out/demo/ (Blender-rendered capture, fit, overlays) and out/paper_quick.json"

test: venv
	$(PY) -m pytest -q tests

bench: venv
	$(PY) -m addon bench --json out/bench.json >/dev/null

paper: venv
	$(PY) -m addon paper --json out/paper.json --out out/paper >/dev/null

extension: venv
	$(PY) tools/build_extension.py

clean:
	rm -rf out dist

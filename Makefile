# Silhouette Cloth Fit: every command sets up its own environment first.
#   make demo   - the paper scenario on the built-in lab18 rig: Blender-rendered observations, fit,
#                 overlays and the pictures of docs/demo.md (and the README's first picture) under out/demo, Table 1 in out/
#   make test   - the whole test suite (pure core + Blender layer through the bpy module)
#   make lint   - ruff check and ruff format --check (pyproject.toml [tool.ruff])
#   make bench  - speed figures (out/bench.json)
#   make paper  - the full paper protocol (Table 1, Fig. 8, Table 2, optimisers; out/paper.json)
#   make docs   - the docs site (MkDocs, strict: a broken link or reference fails) -> out/site
#   make docs-check   - every figure in README.md and docs/*.md against its recording in docs/figures/ (in make test)
#   make docs-images  - run the demo again, record its figures (docs/figures/demo.json), copy its pictures to docs/img
#   make docs-refresh - re-record every cheap source (demo, identifiability, ...) and regenerate the generated blocks
#   make docs-rerun   - run the cheap sources again and compare with their recordings (nothing written)
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv demo test lint bench paper extension clean docs docs-check docs-images docs-refresh docs-rerun

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
	$(PY) -m clothfit paper --quick --json out/paper_quick.json --out out/paper_quick --only table1 --force >/dev/null
	@echo "demo: pictures in out/demo/pictures/ (first guess vs fit, error curve, parameters), figures in out/demo/summary.json, capture/fit/overlays in out/demo/capture, Table 1 in out/paper_quick.json; the fits' verdicts:"
	@$(PY) -m clothfit verdict out/demo/capture/fit_result*.json >/dev/null

test: venv
	$(PY) -m pytest -q tests lab/tests

lint: venv
	$(PY) -m ruff check .
	$(PY) -m ruff format --check .

bench: venv
	$(PY) -m clothfit bench --json out/bench.json --force >/dev/null

paper: venv
	$(PY) -m clothfit paper --json out/paper.json --out out/paper --force >/dev/null

extension: venv
	$(PY) tools/build_extension.py

docs: venv
	NO_MKDOCS_2_WARNING=1 $(PY) -m mkdocs build --strict --site-dir out/site

docs-check: venv
	$(PY) tools/docs_check.py

docs-images: venv
	$(PY) tools/figures.py record demo paper_quick
	$(PY) tools/figures.py pictures
	$(PY) tools/docs_check.py --write

docs-refresh: venv
	$(PY) tools/figures.py record cheap
	$(PY) tools/figures.py pictures
	$(PY) tools/docs_check.py --write

docs-rerun: venv
	$(PY) tools/figures.py rerun

clean:
	rm -rf out dist

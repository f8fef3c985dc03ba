# Lengths & Angles: developer entry points.  Run `make help`.
SHELL := /bin/bash
PYTHON_BOOTSTRAP ?= python3.11
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: help venv demo test extension extension-split extension-validate samples bench clean distclean lint

help:
	@echo "make venv       create $(VENV) (Python 3.11) and install lacore[test] in editable mode"
	@echo "make demo       encode a shared mesh (CLI) and a generated Blender scene (add-on) into demo_output/"
	@echo "make test       run the test suite (pytest)"
	@echo "make extension  download the bundled wheels (4 platforms) and build dist/lengths_angles-*.zip"
	@echo "make extension-split  one smaller zip per platform (each with only its wheels)"
	@echo "make samples    generate the sample .blend files into blend_samples/"
	@echo "make bench      run benchmarks/*.py"
	@echo "make lint       ruff check"
	@echo "make clean      remove build/test/demo outputs (distclean: also $(VENV) and wheels/)"

$(PY):
	$(PYTHON_BOOTSTRAP) -m venv $(VENV)

# Re-installs only when pyproject.toml changes (or the stamp is missing).
$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -e ".[test]"
	touch $(STAMP)

venv: $(STAMP)

demo: venv
	$(PY) scripts/demo.py --output demo_output

test: venv
	$(PY) -m pytest -q

lint: venv
	$(PY) -m ruff check .

# Wheels: pip download --only-binary=:all: --platform ... --python-version 3.11 --no-deps
# (one call per platform, skipped when the wheel is already in ./wheels), then
# blender_ext.py build --source-dir . --output-dir dist, then blender_ext.py validate.
extension: venv
	$(PY) scripts/build_extension.py --output-dir dist

extension-split: venv
	$(PY) scripts/build_extension.py --output-dir dist --split-platforms

samples: venv
	$(PY) scripts/make_samples.py --output blend_samples

bench: venv
	@set -e; shopt -s nullglob; files=(benchmarks/*.py); \
	if [ $${#files[@]} -eq 0 ]; then echo "no benchmarks"; fi; \
	for f in "$${files[@]}"; do echo "== $$f"; $(PY) "$$f"; done

clean:
	rm -rf dist demo_output blend_samples .pytest_cache .ruff_cache build *.egg-info
	find . -path ./$(VENV) -prune -o -name __pycache__ -type d -print0 | xargs -0 rm -rf

distclean: clean
	rm -rf $(VENV) wheels

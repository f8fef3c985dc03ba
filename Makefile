# Lengths & Angles: developer entry points.  Run `make help`.
SHELL := /bin/bash
PYTHON_BOOTSTRAP ?= python3.11
# Python 3.13 (Blender 5.1/5.2's Python): pyenv's by default
PYTHON313 ?= $(shell pyenv root 2>/dev/null || echo $$HOME/.pyenv)/versions/3.13.0/bin/python3.13
# The venvs (reused between runs; override their locations, e.g. `make test VENV_BLENDER52=/cache/b52`):
#   VENV            Python 3.11, NumPy 1.26, lacore[test]: the lacore tests + pytest driver of the Blender checks
#   VENV_NP2        Python 3.13, NumPy 2.5, lacore[test]: the lacore tests again under NumPy 2
#   VENV_BLENDER42  Python 3.11, bpy 4.2.x + NumPy 1.26 ONLY: Blender 4.2 LTS (the oldest supported)
#   VENV_BLENDER52  Python 3.13, bpy 5.2.x (NumPy 2.5) ONLY: Blender 5.2 (the newest)
# The bpy venvs must hold bpy alone: an installed SciPy would hide the extension's bundled wheels.
VENV ?= .venv
VENV_NP2 ?= .venv-np2
VENV_BLENDER42 ?= .venv-blender42
VENV_BLENDER52 ?= .venv-blender52
BPY42 ?= bpy==4.2.23
NUMPY_BLENDER42 ?= numpy==1.26.4
BPY52 ?= bpy==5.2.3
NUMPY1 ?= numpy>=1.26,<2
NUMPY2 ?= numpy>=2.5,<2.6
PY := $(VENV)/bin/python
PY_NP2 := $(VENV_NP2)/bin/python
STAMP := $(VENV)/.installed-stamp
STAMP_NP2 := $(VENV_NP2)/.installed-stamp
STAMP_BLENDER42 := $(VENV_BLENDER42)/.stamp-$(BPY42)-$(NUMPY_BLENDER42)
STAMP_BLENDER52 := $(VENV_BLENDER52)/.stamp-$(BPY52)
BLENDER_PYTHONS := 4.2=$(abspath $(VENV_BLENDER42))/bin/python:5.2=$(abspath $(VENV_BLENDER52))/bin/python

.PHONY: help venv venv-np2 venv-blender demo test test-np2 test-kernels extension extension-split extension-validate samples bench bench-quick clean distclean lint

help:
	@echo "make venv       create $(VENV) (Python 3.11, NumPy 1.26) and install lacore[test] in editable mode"
	@echo "make venv-np2   create $(VENV_NP2) (Python 3.13, NumPy 2.5) with lacore[test]"
	@echo "make venv-blender  create $(VENV_BLENDER42) ($(BPY42)) and $(VENV_BLENDER52) ($(BPY52)), bpy only"
	@echo "make demo       encode a shared mesh (CLI) and a generated Blender scene (add-on) into demo_output/"
	@echo "                (.blend files saved with bpy 4.2: they open in 4.2 to 5.2; panel pictures drawn with 5.2)"
	@echo "make test       the whole suite: lacore under NumPy 1.26 and 2.5, wheel tags, Blender checks on bpy 4.2 and 5.2,"
	@echo "                and the numerically sensitive tests again on other SIMD/BLAS kernels (make test-kernels)"
	@echo "make extension  download the bundled wheels (4 platforms) and build dist/lengths_angles-*.zip"
	@echo "make extension-split  one smaller zip per platform (each with only its wheels)"
	@echo "make samples    generate the sample .blend files into blend_samples/ (with bpy 4.2: they open in 4.2 to 5.2)"
	@echo "make bench      run every benchmark, store its JSON in docs/benchmarks/, rewrite docs/benchmarks.md"
	@echo "make bench-quick  the same with the quick variants"
	@echo "make lint       ruff check"
	@echo "make clean      remove build/test/demo outputs (distclean: also the venvs and wheels/)"

$(PY):
	$(PYTHON_BOOTSTRAP) -m venv $(VENV)

# Re-installs only when pyproject.toml changes (or the stamp is missing).
$(STAMP): pyproject.toml | $(PY)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install -e ".[test]" "$(NUMPY1)"
	touch $(STAMP)

venv: $(STAMP)

$(PY_NP2):
	$(PYTHON313) -m venv $(VENV_NP2)

$(STAMP_NP2): pyproject.toml | $(PY_NP2)
	$(PY_NP2) -m pip install --upgrade pip
	$(PY_NP2) -m pip install -e ".[test]" "$(NUMPY2)"
	touch $(STAMP_NP2)

venv-np2: $(STAMP_NP2)

# bpy ONLY (plus the NumPy that Blender 4.2 ships); the stamp names the pins, so changing them reinstalls.
$(STAMP_BLENDER42):
	rm -f $(VENV_BLENDER42)/.stamp-*
	test -x $(VENV_BLENDER42)/bin/python || $(PYTHON_BOOTSTRAP) -m venv $(VENV_BLENDER42)
	$(VENV_BLENDER42)/bin/python -m pip install "$(BPY42)" "$(NUMPY_BLENDER42)"
	touch "$@"

$(STAMP_BLENDER52):
	rm -f $(VENV_BLENDER52)/.stamp-*
	test -x $(VENV_BLENDER52)/bin/python || $(PYTHON313) -m venv $(VENV_BLENDER52)
	$(VENV_BLENDER52)/bin/python -m pip install "$(BPY52)"
	touch "$@"

venv-blender: $(STAMP_BLENDER42) $(STAMP_BLENDER52)

# The Blender steps that save .blend files run in bpy 4.2's venv (SciPy & co. from $(VENV), same Python 3.11), as
# `make samples`: Blender 4.2 cannot open a .blend saved by 5.x, and every newer Blender opens 4.2's.  The panel
# pictures are drawn in bpy 5.2's venv, finding SciPy & co. in $(VENV_NP2) (same Python 3.13).
demo: venv venv-np2 $(STAMP_BLENDER42) $(STAMP_BLENDER52)
	LACORE_DEMO_BLENDER_PYTHON=$(abspath $(VENV_BLENDER42))/bin/python \
	LACORE_DEMO_BLENDER_PYTHONPATH=$$($(PY) -c "import sysconfig; print(sysconfig.get_paths()['purelib'])") \
	LACORE_DEMO_PANEL_BLENDER_PYTHON=$(abspath $(VENV_BLENDER52))/bin/python \
	LACORE_DEMO_PANEL_BLENDER_PYTHONPATH=$$($(PY_NP2) -c "import sysconfig; print(sysconfig.get_paths()['purelib'])") \
	$(PY) scripts/demo.py --output demo_output

# 1. everything (lacore under NumPy 1.26, wheel-tag check, Blender checks on bpy 4.2 AND 5.2: a missing one fails)
# 2. the lacore tests again under NumPy 2.5 (Python 3.13)
# 3. the numerically sensitive tests (marker `numerics`) again on other SIMD and BLAS kernels (~1-2 min)
test: venv venv-np2 venv-blender
	LACORE_REQUIRE_BLENDERS=1 LACORE_BLENDER_PYTHONS="$(BLENDER_PYTHONS)" $(PY) -m pytest -q
	$(MAKE) --no-print-directory test-np2
	$(MAKE) --no-print-directory test-kernels

test-np2: venv-np2
	$(PY_NP2) -m pytest -q --ignore-glob="tests/test_blender_*"

# NPY_DISABLE_CPU_FEATURES (every SIMD feature NumPy dispatches to on this CPU) and an older OPENBLAS_CORETYPE,
# computed at run time by scripts/other_kernels.py: a result that depends on the CPU fails here, not on the next one.
test-kernels: venv
	$(PY) scripts/other_kernels.py $(PY) -m pytest -q -m numerics --ignore-glob="tests/test_blender_*"

lint: venv
	$(PY) -m ruff check .

# Wheels: pip download --only-binary=:all: --platform ... --python-version 3.11 --no-deps
# (one call per platform, skipped when the wheel is already in ./wheels), then
# blender_ext.py build --source-dir . --output-dir dist, then blender_ext.py validate.
# Built with Blender 5.2's blender_ext.py (bpy venv); the zip holds wheels for Python 3.11 and 3.13.
extension: $(STAMP_BLENDER52)
	$(VENV_BLENDER52)/bin/python scripts/build_extension.py --output-dir dist

extension-split: $(STAMP_BLENDER52)
	$(VENV_BLENDER52)/bin/python scripts/build_extension.py --output-dir dist --split-platforms

# Saved by the oldest supported Blender (bpy 4.2, SciPy & co. from $(VENV), same Python 3.11): Blender 4.2 cannot
# open a .blend saved by 5.x, and every newer Blender opens 4.2's.
samples: venv $(STAMP_BLENDER42)
	PYTHONPATH=$$($(PY) -c "import sysconfig; print(sysconfig.get_paths()['purelib'])") \
	$(VENV_BLENDER42)/bin/python scripts/make_samples.py --output blend_samples

# bench_blender_*.py need bpy AND SciPy in one Python: bpy 5.2's venv with $(VENV_NP2)'s packages on the path.
# scripts/run_benchmarks.py stores each benchmark's JSON in docs/benchmarks/; scripts/benchmark_docs.py then
# rewrites docs/benchmarks.md and the README's measured tables from them.
BENCH_RUN = $(PY) scripts/run_benchmarks.py --python $(abspath $(PY)) \
	--blender-python $(abspath $(VENV_BLENDER52))/bin/python \
	--blender-pythonpath "$$($(PY_NP2) -c "import sysconfig; print(sysconfig.get_paths()['purelib'])")"

bench: venv venv-np2 $(STAMP_BLENDER52)
	$(BENCH_RUN)
	$(PY) scripts/benchmark_docs.py

bench-quick: venv venv-np2 $(STAMP_BLENDER52)
	$(BENCH_RUN) --quick
	$(PY) scripts/benchmark_docs.py

clean:
	rm -rf dist demo_output blend_samples .pytest_cache .ruff_cache build *.egg-info
	find . -path "./.venv*" -prune -o -path ./$(VENV) -prune -o -name __pycache__ -type d -print0 | xargs -0 rm -rf

distclean: clean
	rm -rf $(VENV) $(VENV_NP2) $(VENV_BLENDER42) $(VENV_BLENDER52) wheels

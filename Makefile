# Two commands for a newcomer: `make experiment` and `make test`. Each sets up
# .venv on first use (CPU build of torch first, so nothing pulls CUDA packages).
PYTHON ?= python3
VENV := .venv
STAMP := $(VENV)/.installed

$(STAMP): pyproject.toml constraints.txt setup.py components/body/_servo.c components/body/_arm.c
	$(PYTHON) -m venv $(VENV)
	$(VENV)/bin/pip install --quiet torch==2.13.0
	$(VENV)/bin/pip install --quiet -c constraints.txt -e '.[test]'
	@# Ecos's library (ecospy) links to Intel TBB: Debian's libtbb12, installed where this user may; else named once
	@ldconfig -p 2>/dev/null | grep -q 'libtbb\.so\.12 ' || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
		{ apt-get install -y -qq libtbb12 || { apt-get update -qq && apt-get install -y -qq libtbb12; }; } >/dev/null 2>&1; } || \
		echo "make setup: libtbb.so.12 is missing (Debian: apt-get install libtbb12): rhi run-system --master ecos refuses without it"
	touch $(STAMP)

.PHONY: setup test test-kernels experiment docs tutorial
setup: $(STAMP)

# Two xdist workers, a module to each (modules share expensive fixtures); TEST_WORKERS=0 runs in one process.
TEST_WORKERS ?= 2
test: $(STAMP)
	$(VENV)/bin/python -m pytest -q --durations=20 -n $(TEST_WORKERS) --dist loadfile

# The numeric tests again under the next kernels below this CPU's (AVX-512 -> AVX2 -> baseline): another CPU's
# rounding (tests/kernels.py; python -m tests.kernels --all: every set below).
test-kernels: $(STAMP)
	$(VENV)/bin/python -m tests.kernels

# examples/tutorial.ipynb run at its full size and stored with its outputs, wall time and machine (tests/notebook.py).
tutorial: $(STAMP)
	$(VENV)/bin/python -m tests.notebook

experiment: $(STAMP)
	$(VENV)/bin/rhi experiment --out results

# The documentation site with the API reference generated from the docstrings (mkdocs.yml), into site/; strict:
# a broken link or a docstring griffe cannot read fails it. `$(VENV)/bin/python -m mkdocs serve` to browse.
docs: $(STAMP)
	$(VENV)/bin/python -m mkdocs build --strict --site-dir site

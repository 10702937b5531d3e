# Two entry points for a fresh machine (Python 3.11, nothing installed): `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
# evo (GPL-3.0) is a test-time oracle only: it lives in its own venv and is never imported by slamobs.
EVO_VENV  ?= .venv-evo
EVO_STAMP := $(EVO_VENV)/.installed-stamp

.PHONY: demo test clean bytecode

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	$(MAKE) --no-print-directory bytecode
	touch $(STAMP)

$(EVO_STAMP):
	$(PYTHON) -m venv $(EVO_VENV)
	$(EVO_VENV)/bin/python -m pip install --quiet evo==1.38.1
	touch $(EVO_STAMP)

## slamobs's bytecode beside its sources, as a wheel's install writes it: where Python is told to write none
## (PYTHONDONTWRITEBYTECODE, common in containers) every start would compile ~100 modules (0.25-0.3 CPU s).
bytecode:
	$(BIN)/python -m compileall -q __init__.py pipeline cli

## Set up and run the fast-adaptation observer on a shipped sample log (output in demo_out/).
demo: $(STAMP) bytecode
	$(BIN)/slamobs info sample_logs/figure8.mcap
	$(BIN)/slamobs run sample_logs/figure8.mcap -o demo_out/figure8 --force

## The suite's pytest workers: `auto` is one per core (`make test WORKERS=3` to try another count).
WORKERS ?= auto

## Set up, check the code's shape (ruff lint and format, import-linter's layers), then run the test suite (with
## evo as an oracle in its own venv) on $(WORKERS) pytest workers; a test module stays on one worker
## (--dist loadscope), so its module fixtures are built once, and the modules go out longest first
## (tests/conftest.py's LONGEST_FIRST; xdist's own order, most tests first, is turned off).
test: $(STAMP) $(EVO_STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .
	$(BIN)/lint-imports
	SLAMOBS_EVO_PYTHON=$(abspath $(EVO_VENV))/bin/python $(BIN)/python -m pytest -q -n $(WORKERS) --dist loadscope --no-loadscope-reorder

clean:
	rm -rf $(VENV) $(EVO_VENV) demo_out

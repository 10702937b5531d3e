# Two entry points for a fresh machine (Python 3.11, nothing installed): `make demo` and `make test`.
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp

.PHONY: demo test clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

## Set up and run the fast-adaptation observer on a shipped sample log (output in demo_out/).
demo: $(STAMP)
	$(BIN)/slamobs info sample_logs/figure8.mcap
	$(BIN)/slamobs run sample_logs/figure8.mcap -o demo_out/figure8 --force

## Set up and run the test suite.
test: $(STAMP)
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) demo_out

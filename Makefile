# Two entry points (see README): `make demo` and `make test`. Both create the
# virtual environment in .venv when it is missing and install fgloc into it.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.fgloc-installed

.PHONY: demo test bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,report]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fgloc demo -o out

test: $(STAMP)
	$(PY) -m pytest

clean:
	rm -rf out .pytest_cache

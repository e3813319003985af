# Two entry points (see README): `make demo` and `make test`. Both create the
# virtual environment in .venv when it is missing and install fgloc into it.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.fgloc-installed

.PHONY: demo test lint bench clean

$(STAMP): pyproject.toml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[dev,report]'
	@touch $(STAMP)

demo: $(STAMP)
	$(VENV)/bin/fgloc demo -o out

# Two workers (pytest-xdist, work stealing) keep the suite within CI's ten minutes on two cores.
# Module fixtures run once per worker that takes a test of the module; tests must not share mutable state.
test: lint
	$(PY) -m pytest -n 2 --dist worksteal

# Static checks on the installed layout (a plain, non-editable install into build/pkg):
# the wheel's only top-level package is fgloc, the old names do not import, the
# layers contract holds, ruff and mypy are clean.
PKG := build/pkg
lint: $(STAMP)
	$(VENV)/bin/ruff check .
	rm -rf build && $(PY) -m pip install -q --no-deps --target $(PKG) . 2>&1 | grep -v '^WARNING: Location' || true
	test "$$(cat $(PKG)/fgloc-*.dist-info/top_level.txt)" = fgloc
	cd /tmp && PYTHONPATH=$(CURDIR)/$(PKG) $(CURDIR)/$(PY) -c "import fgloc.factors, fgloc.drivers, sys; \
	  assert fgloc.__file__.startswith('$(CURDIR)/$(PKG)/'), fgloc.__file__; \
	  bad = [m for m in ('factors', 'drivers') if __import__('importlib.util').util.find_spec(m)]; \
	  sys.exit(f'importable old top-level names: {bad}' if bad else 0)"
	cd $(PKG) && $(CURDIR)/$(VENV)/bin/lint-imports --no-cache $(CURDIR)/pyproject.toml
	cp -r tests scripts $(PKG)/  # type-check tests and scripts against the installed layout too
	cd $(PKG) && $(CURDIR)/$(VENV)/bin/mypy --config-file $(CURDIR)/pyproject.toml fgloc tests scripts

clean:
	rm -rf out .pytest_cache build

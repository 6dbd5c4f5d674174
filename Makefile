# gbo-envs: the README's commands. Everything runs inside .venv.
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(VENV)/bin/pip
STAMP := $(VENV)/.installed-stamp

# The numerical kernels of every command, on any x86-64 CPU with AVX2: OpenBLAS's Haswell kernels (numpy and scipy
# each load an OpenBLAS that otherwise picks its kernels by the CPU), and numpy's loops, torch's and its MKL's
# without AVX-512. The suite's references are built with these (evaluation.references.REFERENCE_BLAS_KERNELS); other
# kernels change a GP's last bits, and a run can part from its reference after a few experiments
# (tests/evaluation/test_reference_reproduction.py)
ifeq ($(shell uname -m),x86_64)
export OPENBLAS_CORETYPE ?= Haswell
export NPY_DISABLE_CPU_FEATURES ?= X86_V4 AVX512_ICL AVX512_SPR
export ATEN_CPU_CAPABILITY ?= avx2
export MKL_ENABLE_INSTRUCTIONS ?= AVX2
endif

.PHONY: setup chromium demo test test-fast bench lint clean

setup: $(STAMP)

# Debian's chromium for the browser test of the HTML reports (tests/evaluation/test_report_browser.py):
# installed only where missing and when we are root with apt-get; never fails (the test then skips).
# make test depends on it; make demo does not need it
chromium:
	@command -v chromium >/dev/null 2>&1 || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null 2>&1; then \
	    { apt-get update && apt-get install -y chromium; } \
	      || echo "note: could not install chromium; the browser test of the reports will skip"; \
	  else \
	    echo "note: chromium not found (as root: apt-get install -y chromium); the browser test of the reports will skip"; \
	  fi; }

# torch first, pinned to the CPU build, so that stable-baselines3 never pulls a CUDA build; then the project with
# the versions of constraints.txt (the environment the suite's references are checked and rebuilt in); then the project's
# bytecode, as pip writes it for a regular install: where PYTHONDONTWRITEBYTECODE is set (Docker images, CI) every
# command would otherwise compile the project's modules again (0.17 s of each gbo twin diagnose); then the compiled
# simulation, into numba's cache beside the package (gbo_envs/physics/kernels.py): compiled once here (it prints the seconds), not
# by the first command, nor by each process of make test that needs it first
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --progress-bar on "torch==2.13.0"
	$(PIP) install --progress-bar on -c constraints.txt -e ".[all]"
	$(PY) -m compileall -q agents gbo_envs evaluation
	$(PY) -c "from gbo_envs.physics.kernels import warm_up; print(f'compiled kernels: {warm_up():.1f} s')"
	touch $(STAMP)

demo: setup
	$(PY) -m evaluation.cli demo --out out/demo

# the whole suite (CI runs this); pytest-xdist spreads it over WORKERS processes
WORKERS ?= 2
test: setup chromium
	$(PY) -m pytest -n $(WORKERS)

# everything but the tests marked slow (twin diagnosis, rig surfaces, processes, clusters)
test-fast: setup
	$(PY) -m pytest -n $(WORKERS) -m "not slow"

bench: setup
	$(PY) benchmarks/run_all.py --out out/bench

# ruff, then import-linter's contracts in pyproject.toml (the layers and no cycles in agents.twin)
lint: setup
	$(VENV)/bin/ruff check .
	PYTHONPATH=$(CURDIR) $(VENV)/bin/lint-imports

clean:
	rm -rf out .pytest_cache .ruff_cache

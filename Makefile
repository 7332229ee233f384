# One target per thing a person does. `make demo` and `make test` set everything up.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: setup demo test bench bench-gpu lint tables tables-list clean

# A virtual environment with pinned, tested versions (constraints.txt) from PyPI only.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(PY) -m jaxmocap.cli demo --out out/demo

# Names and progress as they run (-v), and the ten slowest tests at the end. Two processes,
# each taking whole test files (a file's jitted fixtures compile once); TEST_WORKERS=0 runs
# in this process alone.
TEST_WORKERS ?= 2
test: setup
	$(PY) -m pytest -v --durations=10 -n $(TEST_WORKERS) --dist loadfile

# ruff (pinned in constraints.txt): the rules and the format (line length 120) in pyproject.toml.
# The suite checks the same (tests/test_layers.py), so CI refuses what `make lint` would.
lint: setup
	$(VENV)/bin/ruff check jaxmocap tests benchmarks experiments
	$(VENV)/bin/ruff format --check jaxmocap tests benchmarks experiments

bench: setup
	$(PY) benchmarks/body_forward.py

# The GPU rows of the README's table (results/*_gpu.json). Needs a CUDA build of jaxlib,
# e.g. `$(PY) -m pip install "jax[cuda12]==<the pinned jax>"`; refuses to run on CPU.
GPU_BENCHES := body_forward skinning_variants sip_speed solver_border physics_check
bench-gpu: setup
	@$(PY) -c "import jax, sys; b = jax.default_backend(); sys.exit(0 if b == 'gpu' else f'make bench-gpu: JAX sees no GPU (backend {b!r}); install a CUDA jaxlib, e.g. pip install \"jax[cuda12]\"')"
	for b in $(GPU_BENCHES); do $(PY) benchmarks/$$b.py --suffix gpu || exit 1; done

# Every committed table under experiments/results/ from the current code: the CPU ones run
# here (each records its commit, command, split and data in experiments/results/
# provenance.json); the GPU ones are listed with their commands (`make tables-list`).
tables: setup
	$(PY) experiments/make_tables.py

tables-list: setup
	$(PY) experiments/make_tables.py --list

clean:
	rm -rf $(VENV) out .pytest_cache

# One target per thing a person does. `make demo` and `make test` set everything up.
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed-stamp

.PHONY: setup demo test bench bench-gpu lint clean

# A virtual environment with pinned, tested versions (constraints.txt) from PyPI only.
$(STAMP): pyproject.toml constraints.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet --upgrade pip
	$(PY) -m pip install --quiet -c constraints.txt -e '.[test]'
	touch $(STAMP)

setup: $(STAMP)

demo: setup
	$(PY) -m jaxmocap.cli demo --out out/demo

test: setup
	$(PY) -m pytest -q

bench: setup
	$(PY) benchmarks/body_forward.py

clean:
	rm -rf $(VENV) out .pytest_cache

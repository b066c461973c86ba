# tvf: `make test` and `make quickstart` work on a fresh machine (they build .venv first).
PYTHON ?= python3
VENV ?= .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed

.PHONY: venv test test-all lint quickstart reproduce bench mutate clean

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --upgrade pip
	# torch is pinned to the CPU build that lies on these machines; an unpinned torch pulls CUDA.
	$(PY) -m pip install -q "torch==2.13.0"
	$(PY) -m pip install -q -e ".[dev]"
	touch $(STAMP)

venv: $(STAMP)

test: $(STAMP)
	$(PY) -m ruff check src tests benchmarks
	$(PY) -m pytest -n 2 --dist loadfile -q

test-all: $(STAMP)
	$(PY) -m pytest -n 2 --dist loadfile -q -m ""

lint: $(STAMP)
	$(PY) -m ruff check src tests benchmarks
	$(PY) -m ruff format --check src tests benchmarks

quickstart: $(STAMP)
	$(VENV)/bin/tvf quickstart --out out/quickstart

# Re-train the shipped lite weights from scratch (data, C4 GCTN, VF and its second phase, all evaluations, report; about 3 h 50 min on
# 2 CPU cores; re-run to resume) and copy them into src/tvf/weights.
reproduce: $(STAMP)
	$(VENV)/bin/tvf experiment --demos 10 --preset lite --gctn-kernels c4 --vf-tune --out runs/reproduce-lite-10 --ship

bench: $(STAMP)
	$(PY) benchmarks/sim.py
	$(PY) benchmarks/planner.py

# Mutation testing (mutmut, the optional `mutate` extra; config in pyproject.toml) of the success rule, the
# actions, the proposals and the search: hours of CPU, not in CI. Narrow it with a mutant pattern, e.g.
# `make mutate MUTANTS='tvf.sim.success*'`. Results stay in mutants/; the score goes in docs/reliability.md.
MUTANTS ?=
mutate: $(STAMP)
	$(PY) -m pip install -q -e ".[mutate]"
	$(VENV)/bin/mutmut run --max-children 2 $(MUTANTS)
	$(VENV)/bin/mutmut results

clean:
	rm -rf $(VENV) out mutants .pytest_cache .ruff_cache

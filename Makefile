# The two commands: `make run` (the demo on the simulated machine) and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: run test lint typecheck check bench fuzz soak clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)

$(STAMP): pyproject.toml | $(BIN)/python
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev,fast]'
	touch $(STAMP)

DEMO := src/usbmotion/data/demos/1-rounded-square.ngc

run: $(STAMP)
	@mkdir -p out
	$(BIN)/usbmotion run $(DEMO) --plot out/demo-1.png --report out/demo-1.json

test: $(STAMP)
	$(BIN)/python -m pytest -q -x -p no:cacheprovider
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/mypy

lint: $(STAMP)
	$(BIN)/ruff check src tests benchmarks

typecheck: $(STAMP)
	$(BIN)/mypy

# The long runs of the reliability tests: 100,000 examples per fuzz property (make test runs
# a few hundred of each), no per-test timeout; a hang fails its example after 10 s.
FUZZ_EXAMPLES ?= 100000

fuzz: $(STAMP)
	USBMOTION_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) $(BIN)/python -m pytest tests/fuzz -q \
		-p no:cacheprovider -o timeout=0 --hypothesis-show-statistics

# One hour of program on the default machine in virtual time: planned vs executed time and
# memory (tracemalloc). make test runs three minutes of it.
soak: $(STAMP)
	USBMOTION_SOAK_S=3600 $(BIN)/python -m pytest tests/reliability/test_soak.py -q -s \
		-p no:cacheprovider -o timeout=0

bench: $(STAMP)
	$(BIN)/python benchmarks/run_all.py

clean:
	rm -rf $(VENV) build src/*.egg-info .pytest_cache .mypy_cache .ruff_cache

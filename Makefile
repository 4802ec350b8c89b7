# One entry point for humans and CI. Every target builds its own venv from pyproject.toml.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed-stamp
# make run PORT=9000 (0: any free port)
PORT ?= 8080

.PHONY: test lint typecheck unit run demo bench screenshots clean bytecode

$(STAMP): pyproject.toml
	$(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

# The project's own modules byte-compiled, as pip does for an installed wheel (deploy/install.sh):
# the editable install leaves them as source, and where PYTHONDONTWRITEBYTECODE is set every
# command would compile them again at its start (bench/cli_speed.md). Only changed files
# are rewritten.
bytecode: $(STAMP)
	$(BIN)/python -m compileall -q calib daemon drivers simulator

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

typecheck: $(STAMP)
	$(BIN)/mypy

unit: $(STAMP) bytecode
	$(BIN)/pytest

test: lint typecheck unit

# The daemon on the EMULATED cell (examples/sim.toml), store under .state/; Ctrl-C stops it.
run: $(STAMP) bytecode
	$(BIN)/python -m daemon.cli.demo serve --port $(PORT)

# A whole campaign over the REST API against a fresh emulated cell (about 3 minutes).
demo: $(STAMP) bytecode
	$(BIN)/python -m daemon.cli.demo campaign --poses 100

# Solvers on the bundled real data (bench/solver_real.*, its long reference runs cached in
# bench/solver_real_reference.json: `python -m bench.solver_real --recompute` redoes them),
# identification speed and the indicator poll rate (bench/results.*), API latency under load
# while the sampler runs (bench/api_results.*), and the poll rate while identification jobs run
# against idle (bench/sampler_priority.*), and the built-in arms against their makers' data
# (bench/robots.*). Benches that need another checkout or files fetched from public
# repositories (filter speed, hardening5, the KUKA/Fanuc/UR/RAPID real-program checks, issue
# 34's acceptance on real programs: bench/filter_corpus.*) say how to run them at the top of
# their bench/*.md.
bench: $(STAMP) bytecode
	$(BIN)/python -m bench.solver_real
	$(BIN)/python -m bench.min_n
	$(BIN)/python -m bench.drift_bench
	$(BIN)/python -m bench.run
	$(BIN)/python -m bench.api_bench
	$(BIN)/python -m bench.sampler_priority
	$(BIN)/python -m bench.web_bench
	$(BIN)/python -m bench.cli_speed
	$(BIN)/python -m bench.drift_watch
	$(BIN)/python -m bench.robots_check

# The README's screenshots of the operator page (docs/img/web-*.png), on a fresh emulated cell.
screenshots: $(STAMP)
	$(BIN)/python -m bench.web_screenshots

clean:
	rm -rf $(VENV) .mypy_cache .pytest_cache .ruff_cache

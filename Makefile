# tt: the two commands a newcomer runs are `make demo` and `make test`. Every target does its
# own set-up (venv, pinned wheels, CMake path rewrite, colcon build), idempotently.
SHELL := /bin/bash
.SHELLFLAGS := -eu -o pipefail -c
TOP := $(CURDIR)
ENV := set +u; . $(TOP)/env.sh; set -u;
SRC_PY := $(shell find src -name '*.py' -o -name '*.msg' -o -name 'setup.cfg' -o -name '*.yaml' -o -name 'package.xml' | grep -v __pycache__)

.PHONY: all setup build lint test test-fast demo bench report clean

all: build

# Venv, requirements, CMake path rewrite and env.sh (no build).
setup:
	@scripts/setup_workspace.sh --no-build

# colcon build, re-run when any package source changes (the script stamps it). setup first:
# its check of TT_PYTHON against .venv (a demo with TT_PYTHON=3.11 ran 3.12's without a word).
build: setup install/.tt-built
install/.tt-built: $(SRC_PY) requirements.txt constraints.txt scripts/setup_workspace.sh
	@scripts/setup_workspace.sh

lint: setup
	@$(ENV) ruff check src test scripts bench

# The test command (CI runs exactly this): lint, unit tests, graph tests.
test: build lint
	@$(ENV) scripts/run_pytest.sh

demo: build
	@$(ENV) python -m tt_tools.demo

# make bench BENCH='strike prediction' runs those only.
bench: build
	@$(ENV) python bench/run_all.py --out bench/results $(if $(BENCH),--only $(BENCH))

# One report per measured set (different launchers, tables and trackers); the hitting plane
# is at x = -1.2 m because the recorded tracks end near the robot's end line (x = -1.37 m).
report: build
	@$(ENV) cd $(TOP) && for set in mpi_launcher mpi_pam; do \
		tt-identify data/$$set --out docs/report/$$set --hit-plane-x -1.2 || exit 1; \
		python -m tt_prediction.lead_report --data data/$$set --out docs/report/$$set \
			--model docs/report/$$set/model.yaml --hit-plane-x -1.2 || exit 1; done

clean:
	rm -rf build install log env.sh

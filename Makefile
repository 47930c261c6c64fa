# sovd-gateway — the two commands an operator needs are `make run` and `make test`.
PYTHON ?= python3.11
VENV   := .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed
BIND   ?= 127.0.0.1:8080
ARGS   ?=

.PHONY: install run test lint bench reliability screenshot clean

$(STAMP): pyproject.toml
	@command -v $(PYTHON) >/dev/null 2>&1 || { echo "need $(PYTHON) on PATH"; exit 1; }
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[test]'
	touch $(STAMP)

install: $(STAMP)

# The demo robot and a gateway; ARGS go to the gateway (make run ARGS="--allow-fault-clear --log-level debug").
# The demo keeps its state, sockets and logs in demo/var/ (see demo/run.py); its banner says where.
run: $(STAMP)
	$(BIN)/python -m demo.run --bind $(BIND) $(ARGS)

# Four test sessions side by side (each in a ROS domain of its own, a test module stays in one):
# most of the suite's time is waiting on processes (gateways booting, DDS discovery), not using
# the CPU.  The load and fault scenarios of tests/reliability/ (and the bench smoke run) are
# `make reliability`'s: they kept `make test` past 15 minutes on 2 cores.
TEST_JOBS ?= 4

test: $(STAMP)
	$(BIN)/python -m pytest -n $(TEST_JOBS) --dist loadfile --ignore=tests/reliability -m "not slow" $(PYTEST_ARGS)

lint: $(STAMP)
	$(BIN)/ruff check app supervisor rosworker ipc common demo tests bench

bench: $(STAMP)
	$(BIN)/python -m bench.run

reliability: $(STAMP)
	SOVD_RELIABILITY=long $(BIN)/python -m pytest tests/reliability -s -p no:randomly
	$(BIN)/python -m pytest -m slow tests --ignore=tests/reliability -p no:randomly

# The README's picture of the dashboard, taken by its browser test (CI=true: fail, not skip, without chromium).
screenshot: $(STAMP)
	CI=true SOVD_UI_SCREENSHOT=docs/dashboard.png $(BIN)/python -m pytest tests/system/ui/test_ui.py -q -p no:randomly \
		-k live_value_changes_on_screen

clean:
	rm -rf $(VENV) build *.egg-info .pytest_cache

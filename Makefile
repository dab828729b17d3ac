# Two set-up commands: `make demo` and `make test`. Both create .venv and install what they need
# (`make demo` the simulator and the ROS 2 Jazzy wheels, so the node runs on its recording).
# `make test` runs the whole suite with ROS 2 Jazzy's wheels; `make test-kilted` runs the ROS
# tests again with Kilted's, in .venv-kilted (the two distributions' wheels cannot share a venv).
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
PIP := $(BIN)/python -m pip --disable-pip-version-check -q
OUT ?= results/demo
KILTED := .venv-kilted
KILTED_BIN := $(KILTED)/bin
KILTED_PIP := $(KILTED_BIN)/python -m pip --disable-pip-version-check -q

.PHONY: demo test test-kilted bench lint format clean

$(BIN)/python:
	$(PYTHON) -m venv $(VENV)
	$(PIP) install --upgrade pip

$(VENV)/.installed: pyproject.toml | $(BIN)/python
	$(PIP) install -e '.[sim,ros]'
	touch $@

$(VENV)/.installed-test: pyproject.toml tools/build_tf2_msgs.py | $(BIN)/python
	$(PIP) install -e '.[sim,test,ros,rosbuild,dev,cluster]'
	$(BIN)/python tools/build_tf2_msgs.py
	touch $@

$(KILTED_BIN)/python:
	$(PYTHON) -m venv $(KILTED)
	$(KILTED_PIP) install --upgrade pip

# sim, test and cluster as for .venv: pytest imports every test module (tests/test_cluster.py
# imports Ray) before it selects `-m ros`.
$(KILTED)/.installed-test: pyproject.toml tools/build_tf2_msgs.py | $(KILTED_BIN)/python
	$(KILTED_PIP) install -e '.[sim,test,ros-kilted,rosbuild-kilted,cluster]'
	$(KILTED_BIN)/python tools/build_tf2_msgs.py
	touch $@

demo: $(VENV)/.installed
	$(BIN)/scanfuse demo --out $(OUT)

test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -n 2 -q tests

test-kilted: $(KILTED)/.installed-test
	$(KILTED_BIN)/python -m pytest -n 2 -q -m ros tests

bench: $(VENV)/.installed-test
	$(BIN)/python -m benchmarks.run

lint: $(VENV)/.installed-test
	$(BIN)/ruff check src tests benchmarks
	$(BIN)/ruff format --check src tests benchmarks
	$(BIN)/mypy

format: $(VENV)/.installed-test
	$(BIN)/ruff format src tests benchmarks
	$(BIN)/ruff check --fix src tests benchmarks

clean:
	rm -rf $(VENV) $(KILTED) results build src/*.egg-info

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
PYTHON310 ?= python3.10
PY310 := .venv-py310
PY310_BIN := $(PY310)/bin
PY310_PIP := $(PY310_BIN)/python -m pip --disable-pip-version-check -q

.PHONY: demo test test-kilted test-py310 bench lint format clean

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

# Python 3.10 and numpy 1.x, as on a Humble robot (Ubuntu 22.04). Not the test extra: there
# pip's resolver went back through version after version (83 of mkdocs-material) for minutes.
$(PY310)/.installed-test: pyproject.toml
	$(PYTHON310) -m venv $(PY310)
	$(PY310_PIP) install --upgrade pip
	$(PY310_PIP) install -e '.[sim]' 'numpy<2' pytest pytest-xdist hypothesis mcap \
		mcap-ros2-support 'setuptools>=77' 'tomli>=2'
	touch $@

demo: $(VENV)/.installed
	$(BIN)/scanfuse demo --out $(OUT)

test: $(VENV)/.installed-test
	$(BIN)/python -m pytest -n 2 -q tests

test-kilted: $(KILTED)/.installed-test
	$(KILTED_BIN)/python -m pytest -n 2 -q -m ros tests

# Every test but those of ROS 2 over DDS (Humble's rclpy is not on PyPI; the robot's own
# runs the node), the Ray cluster and the documentation site (colcon's build skips itself).
test-py310: $(PY310)/.installed-test
	$(PY310_BIN)/python -m pytest -n 2 -q -m 'not ros' tests --ignore tests/test_cluster.py \
		--ignore tests/test_docs_site.py

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
	rm -rf $(VENV) $(KILTED) $(PY310) results build src/*.egg-info

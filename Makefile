# Two commands on a fresh machine (Python 3.11 + the package registries):
#   make demo   set up .venv/ and replay the bundled sample drive
#   make test   set up .venv/ and run the whole test suite (lint included); .ci/run calls this
# Override the torch wheel for a GPU, e.g.: make test TORCH_SPEC="torch==2.13.0 --index-url <cuda index>"

PYTHON     ?= python3
VENV       ?= .venv
TORCH_SPEC ?= torch==2.13.0
BIN        := $(VENV)/bin
STAMP      := $(VENV)/.deepbbs-installed

# DDS stays on loopback and every run gets its own domain (tests set a per-run one themselves).
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST

.PHONY: venv test demo lint bench clean

venv: $(STAMP)

$(STAMP): setup.py setup.cfg package.xml deepbbs_ros/interfaces.py $(wildcard deepbbs_ros/resources/interfaces/*/package.xml deepbbs_ros/resources/interfaces/*/msg/*)
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/python -m pip install --upgrade pip
	$(BIN)/python -m pip install $(TORCH_SPEC)
	$(BIN)/python -m pip install -e '.[test]'
	# tf2_msgs has no PyPI wheel: built from deepbbs_ros/resources/interfaces/ with the rosidl generators of the ROS wheels (gcc, g++)
	$(BIN)/python -m deepbbs_ros.interfaces
	touch $(STAMP)

test: venv
	$(BIN)/python -m pytest -q tests

lint: venv
	$(BIN)/python -m pytest -q tests/test_lint.py

demo: venv
	$(BIN)/python scripts/demo.py

bench: venv
	$(BIN)/deepbbs-bench

clean:
	rm -rf $(VENV) build install log *.egg-info .pytest_cache .ruff_cache

# thermal_imu_calib — developer entry points. A newcomer types `make demo` and `make test`.
SHELL := /bin/bash
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
ROS_PINS := 'ros-jazzy-rclpy[fastrtps]==7.1.6' 'ros-jazzy-common-interfaces==5.3.6'
BUILD_PINS := 'colcon-core>=0.17' 'colcon-ros>=0.5'
export AMENT_PREFIX_PATH := $(abspath $(VENV))
export PATH := $(abspath $(VENV))/bin:$(PATH)
export ROS_AUTOMATIC_DISCOVERY_RANGE := LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: install demo test lint bench colcon-check clean

install: $(STAMP)

$(STAMP): setup.py package.xml
	@test -x $(PY) || $(PYTHON) -m venv $(VENV)
	@echo "installing dependencies into $(VENV) (log: $(VENV)/install.log)"
	@$(PY) -m pip install -q --upgrade pip 'setuptools<80' wheel > $(VENV)/install.log 2>&1 \
	  && $(PY) -m pip install -q $(ROS_PINS) $(BUILD_PINS) >> $(VENV)/install.log 2>&1 \
	  && $(PY) -m pip install -q -e '.[test]' >> $(VENV)/install.log 2>&1 \
	  || { tail -n 30 $(VENV)/install.log; exit 1; }
	@touch $(STAMP)

demo: install
	@$(PY) scripts/demo.py

test: install
	@ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-$$(( 20 + $$$$ % 80 ))} $(PY) -m pytest -q test

lint: install
	@$(PY) -m pytest -q test/test_flake8.py test/test_pep257.py

bench: install
	@$(PY) bench/run_all.py

colcon-check: install
	@bash scripts/colcon_check.sh

clean:
	rm -rf $(VENV) build install log *.egg-info

# Hypothesis fuzzing of hostile input (loader, bag readers, node callbacks): FUZZ_EXAMPLES
# cases per target (>= 10,000 by default), each under a hard per-case time limit.
FUZZ_EXAMPLES ?= 10000
.PHONY: fuzz
fuzz: install
	@THERMAL_FUZZ_EXAMPLES=$(FUZZ_EXAMPLES) ROS_DOMAIN_ID=$${ROS_DOMAIN_ID:-$$(( 20 + $$$$ % 80 ))} \
	  $(PY) -m pytest -q -p no:cacheprovider test/test_fuzz.py

# cobot_calib_ros: two commands on a fresh clone, `make demo` and `make test`.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
# pytest-xdist workers for `make test`: 3 on 2 cores, since about half of a run's worker time is
# waiting (motion, holds, DDS discovery, timeouts the tests provoke). Fresh clones, session 26:
# 3 workers 8 min 8 s to 8 min 38 s (six runs, green), 4 workers 7 min 19 s to 7 min 52 s (five
# green runs), then a sixth 4-worker run red: test_up's hand-eye skipped 2 of 4 views, "no
# landmarks message of an image stamped after ... within 5 s" (the camera, detector and client
# chain lagging 5 s on the saturated cores; such waits now go on while the chain is behind,
# image_watch.StampedWait). Session 27: a 4-worker run (9 min 30 s) failed test_up after its
# kill -9 of joint_state_monitor (the suite stalled for seconds, README "A killed node can
# stall its peers"), seen only with 4 workers; 3 workers 8 min 2 s to 8 min 44 s, green.
# Session 28, 3 workers: 7 min 24 s to 7 min 57 s once the interface packages were
# byte-compiled and DDS participants announce every second (config/fastdds_large_images.xml)
TEST_WORKERS ?= 3
STAMP := $(VENV)/.stamps

# Keep DDS traffic on this machine (ros2-from-pypi notes).
export ROS_AUTOMATIC_DISCOVERY_RANGE ?= LOCALHOST
export PYTHONDONTWRITEBYTECODE := 1

.PHONY: setup demo test bench clean
.DEFAULT_GOAL := demo

setup: $(STAMP)/package $(STAMP)/postgres

# PostgreSQL server binaries for the database tests' throwaway cluster (tools/pg_cluster.py)
$(STAMP)/postgres: tools/ensure_postgres.sh
	tools/ensure_postgres.sh
	mkdir -p $(STAMP) && touch $@

$(STAMP)/deps: requirements.lock tools/install_deps.sh
	tools/install_deps.sh $(PYTHON) $(VENV) requirements.lock
	mkdir -p $(STAMP) && touch $@

$(STAMP)/msgs: $(STAMP)/deps tools/build_interfaces.sh $(shell find msg_defs -type f)
	tools/build_interfaces.sh $(VENV) msg_defs
	touch $@

# tf2_msgs (/tf, /tf_static) is not on PyPI: build interfaces/tf2_msgs into the venv unless a ROS
# install already provides it (tools/interface_provider.py).
$(STAMP)/tf2_msgs: $(STAMP)/deps tools/build_interfaces.sh tools/interface_provider.py $(shell find interfaces/tf2_msgs -type f)
	tools/build_interfaces.sh --if-missing $(VENV) interfaces/tf2_msgs
	touch $@

# control_msgs (FollowJointTrajectory, a ros2_control arm's trajectory action) is not on PyPI
# either: the same, for interfaces/control_msgs.
$(STAMP)/control_msgs: $(STAMP)/deps tools/build_interfaces.sh tools/interface_provider.py $(shell find interfaces/control_msgs -type f)
	tools/build_interfaces.sh --if-missing $(VENV) interfaces/control_msgs
	touch $@

# compileall: the package's bytecode written once (with PYTHONDONTWRITEBYTECODE set, every node
# and command process would compile its modules again)
$(STAMP)/package: $(STAMP)/msgs $(STAMP)/tf2_msgs $(STAMP)/control_msgs setup.py setup.cfg package.xml $(wildcard config/*.yaml config/cells/*.yaml)
	$(PY) -m pip install --quiet --disable-pip-version-check --no-deps --no-build-isolation -e .
	$(PY) tools/install_ros_prefix.py $(VENV)
	$(PY) -m compileall -q cobot_calib_ros > /dev/null
	touch $@

demo: setup
	$(VENV)/bin/cobot-calib demo

test: setup
	$(PY) -m pytest -q --durations=20 -n $(TEST_WORKERS) --dist loadfile --no-loadscope-reorder test

bench: setup
	$(PY) bench/run_all.py

clean:
	rm -rf $(VENV) build *.egg-info bench-results.json

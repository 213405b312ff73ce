# Set-up is a side effect of every target: the first run builds .venv (pinned, about a minute from
# the local wheels), later runs only check the stamp.
PYTHON ?= python3.11
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
BENCH_VENV := .venv-opencv
BENCH_STAMP := $(BENCH_VENV)/.installed

.PHONY: setup demo test bench constraints clean

setup: $(STAMP)

$(STAMP): requirements.txt constraints.txt fpp_nodes/setup.py
	test -x $(PY) || $(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --quiet -r requirements.txt -c constraints.txt
	$(PY) -m pip install --quiet --no-deps --no-build-isolation -e ./fpp_nodes
	touch $@

demo: setup
	$(VENV)/bin/fpp demo --out out/demo

test: setup
	$(PY) -m pytest -q tests

# OpenCV contrib (structured_light) cannot share an environment with opencv-python-headless.
$(BENCH_STAMP): requirements-bench.txt
	test -x $(BENCH_VENV)/bin/python || $(PYTHON) -m venv $(BENCH_VENV)
	$(BENCH_VENV)/bin/python -m pip install --quiet -r requirements-bench.txt
	touch $@

bench: $(BENCH_STAMP)
	$(BENCH_VENV)/bin/python scripts/bench_psp.py

# Re-pin the transitive dependencies after changing requirements.txt.
constraints: setup
	$(PY) -m pip freeze --exclude-editable \
	  | grep -v -E '^[a-z_]+_(msgs|interfaces|srvs)==|^(rclpy|rcutils|rmw_dds_common|rosidl_[a-z_]+)==' \
	  | sed 's/^torch==\(.*\)+cpu/torch==\1/' > constraints.txt

clean:
	rm -rf $(VENV) $(BENCH_VENV) out

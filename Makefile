# The two commands a newcomer needs: `make demo` and `make test`. Everything else is detail.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
PIP := $(PY) -m pip
DEMO_DRONES ?= 4
DEMO_DURATION ?= 0
# pytest workers: the suite mostly waits on real subprocesses and sockets, so two workers on the
# 2-core CI machine halve its wall time; each test file stays on one worker (--dist loadfile).
TEST_WORKERS ?= 2

.PHONY: help test demo lint typecheck pytest system-deps bench plots clean

help:
	@echo "make demo   - create .venv, install, run the SITL fleet and the ground station"
	@echo "              (until Ctrl-C; DEMO_DURATION=120 stops after 120 s, DEMO_DRONES=4)"
	@echo "make test   - create .venv, install with test extras, run ruff, mypy and pytest"
	@echo "              (about 10 min on two cores; as root it also apt-installs chromium,"
	@echo "              iperf3 and iproute2 for the browser and link tests)"
	@echo "make bench  - run the benchmarks in benchmarks/ (each prints a table)"
	@echo "make plots  - draw the thesis figures of the utility model (4.2-4.13) into out/plots"

$(VENV)/bin/python:
	@$(PYTHON) -m venv $(VENV) 2>/dev/null || { \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing python3-venv with apt-get"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq python3-venv >/dev/null; \
	    rm -rf $(VENV); $(PYTHON) -m venv $(VENV); \
	  else echo "python3 -m venv failed: install python3-venv (Debian: apt-get install python3-venv)"; exit 1; fi; }
	@$(PIP) install -q --upgrade pip

# After installing, the optimiser's numba kernels are compiled once into their disk cache (7-66 s
# on two busy cores), so the first demo's companions load them instead of all compiling them
# at the same time; a failure here only costs the first run that time.
WARM_CACHE := $(PY) -m companion.warm_cache || true

$(VENV)/.installed: $(VENV)/bin/python pyproject.toml
	$(PIP) install -q -e .
	@$(WARM_CACHE)
	@touch $@

$(VENV)/.installed-test: $(VENV)/bin/python pyproject.toml
	$(PIP) install -q -e '.[test]'
	@$(WARM_CACHE)
	@touch $@ $(VENV)/.installed

# Debian packages the tests use: Chromium for the dashboard test, iperf3 and iproute2 for the
# link tests, socat for the serial-cable test (a pty pair), systemd's systemd-analyze to verify
# the companion's unit. Installed when running as root on Debian (as CI does); elsewhere those
# tests skip and say how to enable them.
system-deps:
	@missing=""; \
	command -v chromium >/dev/null || missing="$$missing chromium"; \
	command -v iperf3 >/dev/null || missing="$$missing iperf3"; \
	command -v tc >/dev/null || missing="$$missing iproute2"; \
	command -v socat >/dev/null || missing="$$missing socat"; \
	command -v systemd-analyze >/dev/null || missing="$$missing systemd"; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "installing with apt-get:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else echo "note: missing$$missing (apt-get install$$missing as root); those tests will skip"; fi; \
	fi

lint: $(VENV)/.installed-test
	$(VENV)/bin/ruff check .

typecheck: $(VENV)/.installed-test
	$(VENV)/bin/mypy utility_specs companion/middleware companion/protocol

# MAVProxy, one of the stock clients the simulated vehicle is tested with, lives in its own
# folder: its wheel depends on opencv-python (GUI build), which would clash with the headless
# OpenCV the project uses, and it needs only pymavlink and pyserial at run time.
MAVPROXY_DIR := $(VENV)/mavproxy

$(MAVPROXY_DIR)/bin/mavproxy.py: $(VENV)/bin/python
	-@$(PIP) install -q --no-deps --target $(MAVPROXY_DIR) "MAVProxy>=1.8,<2" "pyserial>=3.5" \
	  || echo "note: MAVProxy not installed; its test will skip"

pytest: $(VENV)/.installed-test system-deps $(MAVPROXY_DIR)/bin/mavproxy.py
	@if [ -x $(MAVPROXY_DIR)/bin/mavproxy.py ]; then \
	  export UAV_SITL_MAVPROXY=$(CURDIR)/$(MAVPROXY_DIR)/bin/mavproxy.py PYTHONPATH=$(CURDIR)/$(MAVPROXY_DIR); fi; \
	$(PY) -m pytest -q -m "not slow" -p no:cacheprovider -n $(TEST_WORKERS) --dist loadfile

test: lint typecheck pytest

demo: $(VENV)/.installed
	$(VENV)/bin/uav-sitl fleet --drones $(DEMO_DRONES) --scene demo --duration $(DEMO_DURATION)

plots: $(VENV)/.installed
	$(VENV)/bin/uav-utility plot all --out out/plots
	$(VENV)/bin/uav-sitl study fig4.13 --out out/plots

bench: $(VENV)/.installed-test
	@status=0; for b in benchmarks/bench_*.py; do echo "== $$b"; $(PY) $$b || status=1; done; exit $$status

clean:
	rm -rf $(VENV) out artifacts .pytest_cache .mypy_cache .ruff_cache

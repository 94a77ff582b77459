# The README's two commands: `make demo` and `make test`. Each sets up what it
# needs (venv, Docker engine, Compose v2, base image) and is safe to re-run.
SHELL := /bin/bash
PYTHON ?= python3
VENV := .venv
PY := $(VENV)/bin/python
ESPDOCK := $(VENV)/bin/espdock
LOCK := requirements/dev.txt

.PHONY: setup test unit demo demo-down bench clean

# The pinned pip (docker/pip-installer.txt says why), then every dependency from the hashed lock
# (`espdock lock` makes it from pyproject.toml's dependencies and `test` extra), then
# espdock itself, whose dependencies are all in it.
# uv, as the lock pins and hashes it, installs the lock: from a fresh clone the venv is
# ready in about half pip's time, and it is on the way of both make commands. uv reads no
# pip.conf, so where uv does not install or cannot install the lock (an index only pip is
# configured for), pip installs the same lock and espdock.
# Its temp dir is the venv's: uv leaves a lock file there for each setuptools tree it builds (espdock, sdists).
UV_INSTALL := TMPDIR=$(abspath $(VENV)) $(VENV)/bin/uv pip install -q --python $(PY)
$(VENV)/.installed: pyproject.toml $(LOCK) docker/pip-installer.txt
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install -q --require-hashes -r docker/pip-installer.txt
	$(PY) -m pip install -q --require-hashes --no-deps -r <(awk '/^uv==/{p=1;print;next} p&&/^ +--hash/{print;next} p{exit}' $(LOCK)) \
	  && $(UV_INSTALL) --require-hashes --compile-bytecode -r $(LOCK) && $(UV_INSTALL) --no-deps -e . \
	  || { echo "make: uv could not install $(LOCK); pip installs it"; \
	       $(PY) -m pip install -q --require-hashes -r $(LOCK) && $(PY) -m pip install -q --no-deps -e .; }
	touch $@

# The test-only system packages (apt) install while the venv does (pip): they share no lock.
# Then the engine, compose plugin and base image (apt again, so after both).
# The venv's install writes its packages' bytecode; this editable install's is written here, since
# where PYTHONDONTWRITEBYTECODE is set (CI machines and Docker images often set it) every espdock
# start compiled its modules again: 0.3 s each (the suite starts espdock about 700 times).
setup:
	bash tests/install-system-deps.sh & deps=$$!; \
	$(MAKE) --no-print-directory $(VENV)/.installed; venv_status=$$?; \
	wait $$deps; deps_status=$$?; \
	exit $$(( venv_status || deps_status ))
	$(PY) -m compileall -q espdock
	$(ESPDOCK) setup

# The firmware host tests (host gcc, no engine) run beside pytest, which mostly waits on
# the engine; their output follows pytest's, and either failing fails the target.
# Three pytest workers, each taking whole modules (their module fixtures build once):
# one worker's image builds and colcon runs fill the others' waits on containers. On two
# cores, three left 8 % idle where two left more and four gained nothing (docs/testing.md).
# Modules go out longest first (tests/longest_first.py sets the order xdist keeps).
test: setup
	$(PY) -m ruff check espdock tests ws/src
	$(PY) -m ruff format --check espdock tests ws/src
	mkdir -p build
	bash tests/firmware/run.sh build/host-tests > build/host-tests.log 2>&1 & firmware=$$!; \
	$(PY) -m pytest -n 3 --dist loadfile --no-loadscope-reorder; status=$$?; \
	wait $$firmware; firmware_status=$$?; \
	cat build/host-tests.log; \
	exit $$(( status || firmware_status ))

# Fast unit tests only: no engine needed.
unit: $(VENV)/.installed
	$(PY) -m pytest tests/unit

# The demo needs no ESP32 (simulators stand in), so only the ROS side is built.
demo: setup
	# Builds ws/ and the runtime image compose.yaml names (espdock/demo:latest: espdock.toml asks for it).
	$(ESPDOCK) build --only ros
	@echo "espdock demo: its console names the camera UI's address (http://127.0.0.1:8080 unless ESPDOCK_DEMO_PORT or ESPDOCK_DEMO_BIND, in the environment or .env, say otherwise); Ctrl-C stops it"
	# --attach demo: one console, and Ctrl-C stops every service, not only `demo`. Ctrl-C is
	# how the demo ends: its 130 is no failure of make's.
	$(ESPDOCK) compose --profile sim up --attach demo || { status=$$?; [ $$status -eq 130 ] || exit $$status; \
	  echo "make demo-down removes the demo's containers and network"; }

demo-down:
	$(ESPDOCK) compose --profile '*' down --remove-orphans

bench: setup
	$(PY) tests/bench/demo_bench.py

clean:
	rm -rf build ws/build ws/install ws/log

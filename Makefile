# Two commands do everything: `make run` and `make test`.
PYTHON ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed
DEV_STAMP := $(VENV)/.installed-dev
# Debian packages. To run: Mesa for headless MuJoCo rendering (EGL and OSMesa). Only for the tests:
# Chromium for browser tests, docker-compose to check docker-compose.yml (the check needs no Docker engine),
# PostgreSQL for the tests of the store on PostgreSQL.
RUN_PACKAGES := libegl1 libegl-mesa0 libgl1 libgles2 libosmesa6
TEST_PACKAGES := chromium docker-compose postgresql
# The suite runs on two pytest workers (pytest-xdist): most tests wait on servers, learners and subprocesses.
PYTEST_ARGS ?= -n 2
export MUJOCO_GL ?= egl
export PYOPENGL_PLATFORM ?= $(MUJOCO_GL)

.PHONY: run test lint install install-dev run-packages test-packages bench clean

run: install
	$(BIN)/raq migrate
	$(BIN)/raq up --demo

test: test-packages install-dev
	$(BIN)/ruff check app cli contract learner robot sim tests bench examples
	@rm -f $(VENV)/pytest-exit-code
	$(BIN)/python -m pytest $(PYTEST_ARGS); code=$$?; echo $$code > $(VENV)/pytest-exit-code; exit $$code

lint: install-dev
	$(BIN)/ruff check app cli contract learner robot sim tests bench examples

# `make run` installs what runs (the project); `make test` adds the test tools (.[dev]). Each has its own stamp,
# so that `make run` never installs the test tools and `make test` installs them once.
install: run-packages $(STAMP)

install-dev: $(DEV_STAMP)

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet --upgrade pip
	$(BIN)/pip install --quiet -e .
	touch $(STAMP)

$(DEV_STAMP): $(STAMP) pyproject.toml
	$(BIN)/pip install --quiet -e '.[dev]'
	touch $(DEV_STAMP)

# $(call require-packages,LIST): install the missing ones with apt-get as root; otherwise print the exact
# apt-get command and fail.
define require-packages
	@missing=""; for p in $(1); do \
	  dpkg-query -W -f='$${Status}' $$p 2>/dev/null | grep -q "install ok installed" || missing="$$missing $$p"; \
	done; \
	if [ -n "$$missing" ]; then \
	  if [ "$$(id -u)" = 0 ] && command -v apt-get >/dev/null; then \
	    echo "Installing system packages:$$missing"; \
	    apt-get update -qq && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq $$missing >/dev/null; \
	  else \
	    echo "Missing system packages:$$missing"; \
	    echo "Install them with: sudo apt-get install$$missing"; exit 1; \
	  fi; \
	fi
endef

run-packages:
	$(call require-packages,$(RUN_PACKAGES))

test-packages:  # what `make run` needs and what only the tests need, in one check
	$(call require-packages,$(RUN_PACKAGES) $(TEST_PACKAGES))

bench: install
	$(BIN)/python bench/env_speed.py
	$(BIN)/python bench/learner_speed.py

clean:
	rm -rf $(VENV) data .pytest_cache

# The two commands a new user needs (see README): `make demo` and `make test`.
PY ?= python3
export MUJOCO_GL ?= egl

.PHONY: install demo test lint

# The demo needs only the deploy side (runtime, driver, MuJoCo rig): no torch, no training extras.
.installed-demo: pyproject.toml scripts/install.sh
	./scripts/install.sh demo
	touch $@

# Tests cover training and export too: every extra.
.installed: pyproject.toml scripts/install.sh
	./scripts/install.sh all
	touch $@

install: .installed

demo: .installed-demo
	$(PY) -m hil_sim.demo

test: .installed
	$(PY) -m ruff check .
	$(PY) -m pytest -q

# The two commands a new user needs (see README): `make demo` and `make test`.
PY ?= python3
export MUJOCO_GL ?= egl

.PHONY: install demo test lint

.installed: pyproject.toml scripts/install.sh
	./scripts/install.sh
	touch .installed

install: .installed

demo: .installed
	$(PY) -m hil_sim --seconds 20 --rate 10 --report runs/demo

test: .installed
	$(PY) -m ruff check .
	$(PY) -m pytest -q

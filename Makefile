# The two commands of the README:
#   make demo   create .venv, install, run the main job on the bundled default
#   make test   create .venv, install, run the test suite
PYTHON ?= python3
VENV   ?= .venv
BIN    := $(VENV)/bin
STAMP  := $(VENV)/.installed-stamp
OUT    ?= out
# Full Bandai archives when present (../shared), else the bundled sample clips.
BANDAI ?= $(firstword $(wildcard ../shared/data/bandai) data/bandai-sample)

.PHONY: install demo test test-slow lint format corpus clean

$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -c requirements.lock -e ".[train,dev]"
	touch $(STAMP)

install: $(STAMP)

# Until the model lands (issue 3/4) the main job is the data pipeline on real clips:
# prepare a corpus from the bundled sample, then render a held-out group scene.
demo: $(STAMP)
	$(BIN)/umf data prepare --bandai data/bandai-sample --out $(OUT)/demo-corpus \
		--train-scenes 40 --val-scenes 10 --test-scenes 10 --test-groups 6
	$(BIN)/umf data list-items $(OUT)/demo-corpus --split test_groups --limit 6
	$(BIN)/umf data show "$$($(BIN)/umf data list-items $(OUT)/demo-corpus --split test_groups --limit 1 | cut -f1)" \
		--corpus $(OUT)/demo-corpus --out $(OUT)/demo-group.gif
	$(BIN)/umf data show "$$($(BIN)/umf data list-items $(OUT)/demo-corpus --split train --limit 1 | cut -f1)" \
		--corpus $(OUT)/demo-corpus --out $(OUT)/demo-pair.mp4

test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

# Slow checks: the full Bandai corpus (needs ../shared), training to convergence.
test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# The full corpus from ../shared/data/bandai (or BANDAI=...).
corpus: $(STAMP)
	$(BIN)/umf data prepare --bandai $(BANDAI) --out $(OUT)/corpus

lint: $(STAMP)
	$(BIN)/ruff check src tests
	$(BIN)/ruff format --check src tests

format: $(STAMP)
	$(BIN)/ruff format src tests
	$(BIN)/ruff check --fix src tests

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .ruff_cache

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

.PHONY: install demo serve test test-slow bench mutation mutation-rerun mutation-sample lint format corpus clean

$(STAMP): pyproject.toml requirements.lock
	$(PYTHON) -m venv $(VENV)
	$(BIN)/pip install --quiet torch==2.13.0
	$(BIN)/pip install --quiet -c requirements.lock -e ".[train,dev]"
	@# from npm: three.js for `umf serve`; the Khronos glTF validator and playwright-core
	@# (drives Debian's chromium, never downloads a browser) for the tests, which skip
	@# without them
	-command -v npm >/dev/null && npm install --silent --no-audit --no-fund \
		--prefix $(VENV)/node three@0.187.0 gltf-validator@2.0.0-dev.3.10 playwright-core@1.65.1
	touch $(STAMP)

install: $(STAMP)

# The main job on the bundled default model: a 3-person scene in every format, then a
# reaction to a real captured bow (person 1 from a BVH file, the others generated).
demo: $(STAMP)
	$(BIN)/umf generate "three people walk side by side" --people 3 --seconds 4 --seed 0 \
		--format npz,gif,mp4,bvh,glb,smpl,humanml3d --out $(OUT)/demo
	$(BIN)/umf react "two people bow to each other" --people 2 --seed 0 \
		--actor data/bandai-sample/Bandai-Namco-Research-Motiondataset-1/data/dataset-1_bow_normal_001.bvh \
		--format npz,gif,glb --out $(OUT)/demo

# The web page: generate scenes and play them in 3-D at http://localhost:8000/
serve: $(STAMP)
	$(BIN)/umf serve

test: $(STAMP)
	$(BIN)/python -m pytest -q -m "not slow"

# Slow checks: the full Bandai corpus (needs ../shared), training to convergence.
test-slow: $(STAMP)
	$(BIN)/python -m pytest -q -m slow

# Speed of the bundled model on this machine (figures in the README).
bench: $(STAMP)
	$(BIN)/python scripts/benchmark.py --out results/benchmark.json

# Mutation testing (mutmut) over the modules of [tool.mutmut] in pyproject.toml; the score
# and every surviving mutant go to results/mutation/. PYTHONPATH puts the mutated copy
# before the editable install.
MUTMUT_RUN := PYTHONPATH=src OMP_NUM_THREADS=1 UMF_GLTF_VALIDATOR=$(abspath $(VENV))/node \
	$(BIN)/mutmut run
MUTATION_REPORT := PATH=$(abspath $(BIN)):$$PATH $(BIN)/python scripts/mutation_report.py \
	--out results/mutation
mutation: $(STAMP)
	$(BIN)/pip install --quiet -c requirements.lock -e ".[mutation]"
	rm -rf mutants
	$(MUTMUT_RUN)
	$(MUTATION_REPORT)

# The survivors (and equivalents) of results/mutation alone, run again after tests were
# written for them: minutes instead of the full run's hours. The mutants that run killed keep
# their outcome; the source must be the one it mutated.
MUTATION_PREVIOUS := results/mutation/mutation.json
mutation-rerun: $(STAMP)
	$(BIN)/pip install --quiet -c requirements.lock -e ".[mutation]"
	rm -rf mutants
	$(MUTMUT_RUN) $$($(BIN)/python scripts/mutation_report.py --previous $(MUTATION_PREVIOUS) --names)
	$(MUTATION_REPORT) --previous $(MUTATION_PREVIOUS)

# One module too slow to run whole (umf.pipeline: each mutant runs the end-to-end tests) scored
# on a seeded sample of its mutants, beside results/mutation's other modules.
MUTATION_SAMPLE ?= umf.pipeline
MUTATION_COUNT ?= 24
MUTATION_SEED ?= 0
mutation-sample: $(STAMP)
	$(BIN)/pip install --quiet -c requirements.lock -e ".[mutation]"
	rm -rf mutants
	$(MUTMUT_RUN) $$($(BIN)/python scripts/mutation_report.py --sample $(MUTATION_SAMPLE) \
		--count $(MUTATION_COUNT) --seed $(MUTATION_SEED) --names)
	$(MUTATION_REPORT) --previous $(MUTATION_PREVIOUS) --sample $(MUTATION_SAMPLE)

# The full corpus: Bandai from ../shared/data/bandai (or BANDAI=...), and where ../shared is
# present (or MOCAP_DATA=...) the real two-person takes (CMU salsa, CMU handshake) and the
# DeepMimic actions, unpacked into $(OUT)/mocap/ beside their captions from data/mocap/.
MOCAP_DATA ?= ../shared/data
MOCAP_LIBS := $(foreach d,cmu-salsa cmu-handshake deepmimic,$(if $(wildcard $(MOCAP_DATA)/$(d)/$(d).tar.xz),$(d)))
corpus: $(STAMP)
	@for d in $(MOCAP_LIBS); do \
		mkdir -p $(OUT)/mocap && tar xJf $(MOCAP_DATA)/$$d/$$d.tar.xz -C $(OUT)/mocap && \
		cp data/mocap/$$d/* $(OUT)/mocap/$$d/ && cp $(MOCAP_DATA)/$$d/README.md $(OUT)/mocap/$$d/SOURCE-README.md; \
		cp $(MOCAP_DATA)/$$d/LICENSE* $(OUT)/mocap/$$d/ 2>/dev/null || true; \
	done
	$(BIN)/umf data prepare --bandai $(BANDAI) $(foreach d,$(MOCAP_LIBS),--mocap $(OUT)/mocap/$(d)) \
		--out $(OUT)/corpus

lint: $(STAMP)
	$(BIN)/ruff check src tests
	$(BIN)/ruff format --check src tests

format: $(STAMP)
	$(BIN)/ruff format src tests
	$(BIN)/ruff check --fix src tests

clean:
	rm -rf $(VENV) $(OUT) .pytest_cache .ruff_cache

# safe_bc: one venv, torch pinned first (local CPU wheel), then the package.
PY ?= python3.11
VENV ?= .venv
BIN := $(VENV)/bin
STUDY ?= default
TRIALS ?=
ARGS ?=
# where `make demos` writes the description of data/demos: an untracked folder, so a local
# collection does not rewrite the committed results/demos (`make demos DESCRIBE=results/demos`
# refreshes those on purpose)
DESCRIBE ?= runs/demos_describe
STAMP := $(VENV)/.installed
# the exact torch both environments install first (the package itself declares a range)
TORCH := torch==2.13.0

.PHONY: install test test-slow lint format bench tune reproduce demos expert ablation renderer beyond-car peers peers-env clean

$(STAMP): pyproject.toml
	test -x $(BIN)/python || $(PY) -m venv $(VENV)
	$(BIN)/pip install -q --upgrade pip
	$(BIN)/pip install -q $(TORCH)
	$(BIN)/pip install -q -e '.[dev,minari]'
	touch $(STAMP)

install: $(STAMP)

test: $(STAMP)
	RAY_AUTH_MODE=disabled $(BIN)/python -m pytest -q

test-slow: $(STAMP)
	RAY_AUTH_MODE=disabled $(BIN)/python -m pytest -q -m slow

lint: $(STAMP)
	$(BIN)/ruff check .
	$(BIN)/ruff format --check .

format: $(STAMP)
	$(BIN)/ruff format .
	$(BIN)/ruff check --fix .

bench: $(STAMP)
	$(BIN)/python -m benchmarks.bench

demos: $(STAMP)
	mkdir -p data
	$(BIN)/safe-bc collect --out data/demos
	$(BIN)/safe-bc describe --demos data/demos --out $(DESCRIBE)

expert: $(STAMP)
	$(BIN)/safe-bc expert --episodes 50 --out results/expert

reproduce: $(STAMP)
	$(BIN)/safe-bc reproduce

# The observation ablation behind PreprocessConfig's defaults (results/ablation/observation/):
# the comparison, whose report step chooses the default from its episodes.
ablation: $(STAMP)
	$(BIN)/safe-bc compare tune_jobs/compare/observation.py --name observation $(ARGS)

# The raster renderer against the exact one (results/ablation/renderer/): frames, cost errors
# and speeds, then exact agents on raster frames, then the whole pipeline on raster frames.
renderer: $(STAMP)
	$(BIN)/python -m scripts.render_accuracy
	for name in renderer pipeline pipeline_table1 pipeline_table1_alpha0; do \
		$(BIN)/safe-bc compare tune_jobs/compare/renderer.py --name $$name $(ARGS) || exit 1; \
	done

# The car's beyond-the-expert design (tune_jobs/compare/selfimprove.py, docs/improvement.md):
# its 12 self-imitation cells, JOBS at a time in processes of their own (one torch thread each;
# a finished cell, committed, is skipped), then the selection table and the two fresh tables.
JOBS ?= 2
BEYOND_CELLS := $(foreach m,si_agent_bar si_expert_bar si_explore si_explore_best2,$(foreach s,0 1 2,$(m):$(s)))
beyond-car: $(STAMP)
	mkdir -p data
	test -d data/demos || $(BIN)/safe-bc collect --out data/demos
	printf '%s\n' $(BEYOND_CELLS) | OMP_NUM_THREADS=1 xargs -P $(JOBS) -I{} \
		$(BIN)/safe-bc compare tune_jobs/compare/selfimprove.py --name beyond_selection --cell {} --workers 0
	for name in beyond_selection beyond beyond_replication; do \
		$(BIN)/safe-bc compare tune_jobs/compare/selfimprove.py --name $$name $(ARGS) || exit 1; \
	done

# OSRL's own code beside safe_bc's methods (docs/peers.md). osrl-lib 0.1.0 pins torch~=1.13 and
# dsrl pulls pygame 2.1 built from source, so `pip install osrl-lib dsrl` fails on Python 3.11:
# the peers get an environment of their own, with the package's torch and OSRL's packages without
# their pins (only what their algorithms and fsrl's loggers import). That environment never
# imports safe_bc: it reads the demonstrations as DSRL's dataset dict (an .npz written by
# safe_bc) and writes each learned actor as TorchScript, which safe_bc evaluates.
PEERS_VENV ?= .venv-peers
PEERS_STAMP := $(PEERS_VENV)/.installed
PEERS_TASK ?= rehab
PEERS_OUT ?= results/peers
PEERS_RUNS ?= runs/peers
PEERS_DEMOS ?= data/$(PEERS_TASK)_demos

$(PEERS_STAMP):
	test -x $(PEERS_VENV)/bin/python || $(PY) -m venv $(PEERS_VENV)
	$(PEERS_VENV)/bin/pip install -q --upgrade pip
	$(PEERS_VENV)/bin/pip install -q $(TORCH)
	$(PEERS_VENV)/bin/pip install -q --no-deps osrl-lib==0.1.0 fast-safe-rl==0.1.0 dsrl==0.1.0
	$(PEERS_VENV)/bin/pip install -q numpy scipy tqdm pyyaml gymnasium tensorboard wandb
	$(PEERS_VENV)/bin/python -c "from osrl.algorithms import BC, BCTrainer, COptiDICE, COptiDICETrainer, CPQ, CPQTrainer"
	touch $(PEERS_STAMP)

peers-env: $(PEERS_STAMP)

# Train OSRL's BC-All, BC-Safe, COptiDICE and CPQ on the task's demonstrations and evaluate them
# beside safe_bc's methods on fresh patients: results/peers/ (ARGS go to the evaluation); the
# demonstrations (PEERS_DEMOS) are collected with the task's defaults if absent.
peers: $(STAMP) $(PEERS_STAMP)
	mkdir -p $(dir $(PEERS_DEMOS))
	test -d $(PEERS_DEMOS) || $(BIN)/safe-bc collect --env $(PEERS_TASK) --out $(PEERS_DEMOS)
	$(BIN)/python -m safe_bc.peers prepare --task $(PEERS_TASK) --demos $(PEERS_DEMOS) --runs $(PEERS_RUNS)
	OMP_NUM_THREADS=1 $(PEERS_VENV)/bin/python peers/osrl_train.py --runs $(PEERS_RUNS)
	$(BIN)/python -m safe_bc.peers evaluate --task $(PEERS_TASK) --demos $(PEERS_DEMOS) --runs $(PEERS_RUNS) --out $(PEERS_OUT) $(ARGS)

# TRIALS=n is another study than the file's: its own results and Tune experiment under
# runs/trials<n>/ (untracked), never over the committed results/<STUDY>/ (docs/cli.md)
tune: $(STAMP)
	$(BIN)/safe-bc tune tune_jobs/$(STUDY).py $(if $(TRIALS),--trials $(TRIALS) --results runs/trials$(TRIALS) --storage runs/trials$(TRIALS)/ray,) $(ARGS)

clean:
	rm -rf $(VENV) $(PEERS_VENV) .pytest_cache .ruff_cache

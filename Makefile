# imix: the two set-up commands of the README, the paper reproduction and the benchmarks.
VENV   ?= .venv
PYTHON ?= python3
PY      = $(VENV)/bin/python
IMIX    = $(VENV)/bin/imix

# The paper's main grid (section 4.2): 4 ES x {CartPole, Acrobot} x {no mixing, EIM} x 25 seeds,
# each ES at its paper generation count. Finished runs are skipped, so an interrupted
# `make reproduce` continues where it stopped. The weight decay is the authors' code's form
# (estool: ranks - 0.05 mean(theta^2), the config default weight_decay_form=estool): the paper's
# published curves come from it, while its text's -0.05|theta|^2 (weight_decay_form=paper) keeps
# population scores far lower (docs: reproducing the paper).
PAPER_GRID = algo=openes,snes,cem,cmaes env=cartpole,acrobot eim=false,true

# torch for the DDPG baseline: the CPU build 2.13.0, installed before the package so that the
# extra's torch>=2.1 is already satisfied (an unpinned torch pulls several GB of CUDA packages;
# on other machines add --index-url https://download.pytorch.org/whl/cpu).
TORCH ?= torch==2.13.0

# The tested stack: `make install` and `make install-all` install the exact versions of
# constraints.txt (numpy, numba, llvmlite, ... : the ones the tests and the published numbers
# ran with; regenerate with tools/freeze_constraints.py). `make install CONSTRAINTS=` installs
# unpinned, as `pip install .` does.
CONSTRAINTS ?= constraints.txt
PIN = $(if $(CONSTRAINTS),-c $(CONSTRAINTS))

# Paper section 4.3: the SNES + EIM grid search (Figs 9-11) and SNES + EIM vs DDPG on
# ContinuousCartPole and its sparse-reward Hard variant (Figs 12-13). DDPG runs at ~420 env
# steps per CPU-second here, so `make reproduce` uses few DDPG seeds (about an hour in all on
# 2 cores); `make reproduce-full` uses 25 seeds everywhere (many hours).
GRID_SEEDS      ?= 5
DDPG_SEEDS      ?= 4
DDPG_HARD_SEEDS ?= 2
SEC43 = eim=true progress=false

.PHONY: install dev install-all bbob docs docs-numbers test test-fast test-install test-extras reproduce reproduce-main reproduce-grid reproduce-ddpg reproduce-full reproduce-quick bench

# `make install` is what the main job needs: the ES runner, plots, eval/render/status, the tests
# (numpy, scipy, numba, gymnasium, hydra, pandas, matplotlib, cma, pytest, pygame; 36 s here).
# `make install-all` adds the DDPG baseline (CPU torch + stable-baselines3), the cluster launchers
# (joblib, submitit, Ray), MuJoCo, TensorBoard (logger=tensorboard) and the docs tools (make docs):
# for `make reproduce-ddpg`, hydra/launcher=..., evaluator=ray, `make reproduce-mujoco`; the tests of
# these extras are skipped without them. CI uses it.
install:  ## create .venv and install imix (non-editable; make dev: editable): runner, plots, render, tests
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install $(PIN) $(EDITABLE) ".[test,render]"
	# pip writes the bytecode of what it installs, but an editable install runs the source tree, whose bytecode Python
	# writes at the first import -- unless PYTHONDONTWRITEBYTECODE is set (as in many containers, and on the VM the
	# README's times come from): then every imix process compiled imix's ~110 modules again, the main process and the
	# seed workers' server at every `imix run` (the main job's whole process 0.95x as long with it written:
	# docs/research/performance.md). Written here once (stale files are recompiled).
	$(if $(EDITABLE),$(PY) -m compileall -q imix_cli hydra_plugins)
	# compile the numba kernels now, once: the first run then compiles nothing, nor does `make test` (the
	# source tree shares the installed copy's kernels: imix_cli/core/numerics/numba_cache.py). How long it takes depends on
	# the CPU's speed, its core count (the kernel groups compile in parallel processes, one per core: fewer cores,
	# longer) and how loaded the machine is (other jobs take those cores): measured 47 s on a fresh install on
	# a 2-core VM, 202 s on a 2-core VM at load 10. From inside the venv
	# folder: run from here, `python -m` would import the source tree, not the installed package
	cd "$(VENV)" && bin/python -m imix_cli.running.warmup
	@echo "imix is installed in $(VENV). Run it as $(IMIX), or put it on PATH for this shell with:  source $(VENV)/bin/activate"

# `make dev` is `make install` with an editable install (pip install -e, the same constraints): the venv runs the source
# tree, so an edit (a new ES, env, key or config) takes effect with no reinstall. A non-editable install runs its own
# copy: after an edit, `make install` again before `imix run algo=<new>` finds it (docs/development.md, Extending imix).
# With the extras: `make install-all EDITABLE=-e`.
EDITABLE ?=
dev:  ## create .venv and install imix editable (pip install -e ".[test,render]", the same constraints): edits take effect with no reinstall
	$(MAKE) install EDITABLE=-e

install-all: install  ## install + the DDPG baseline (CPU torch pin), the cluster launchers, MuJoCo, TensorBoard, the docs tools, COCO (bbob), Optuna (search)
	$(PY) -m pip install $(PIN) "$(TORCH)"
	$(PY) -m pip install $(PIN) $(EDITABLE) ".[all]"

# The tests of the extras `make install-all` adds: one marker per extra (tests/conftest.py, EXTRAS). Without
# its extra a marked test is skipped, so `make test` passes after a plain `make install`.
EXTRA_TESTS = mujoco or ddpg or cluster or tensorboard or docs or bbob or search

# The suite runs on every core (pytest-xdist, `-n auto`; TEST_WORKERS=0 runs it in one process): its tests
# are independent (each writes below its own tmp_path and checks only the processes it started).
TEST_WORKERS ?= auto
XDIST = $(if $(filter 0,$(TEST_WORKERS)),,-n $(TEST_WORKERS))

test:  ## the whole test suite, slow end-to-end tests included (tests of extras not installed are skipped; the warm-up's in test-install)
	$(PY) -m pytest -q $(XDIST) -m "not install"

test-fast:  ## day-to-day: every test not marked slow
	$(PY) -m pytest -q $(XDIST) -m "not slow and not install"

test-install:  ## what a fresh install gives: the warm-up's cold compiles, every README and --help command as shown, whole runs under every BLAS kernel (minutes of CPU; CI runs it once)
	$(PY) -m pytest -q -m install

test-extras:  ## only the tests of the extras (after make install-all; CI runs it after make test)
	$(PY) -m pytest -q -m "$(EXTRA_TESTS)"

reproduce: reproduce-main reproduce-grid reproduce-ddpg  ## the whole paper into results/paper*/

reproduce-main:  ## section 4.2: the main grid + Figs 1-3, 5-8, Table 1 into results/paper/figures/
	$(IMIX) run -m $(PAPER_GRID) experiment=paper progress=false
	$(IMIX) plot experiment=paper didactic=true

reproduce-grid:  ## section 4.3: popsize/sigma/lr grid search (Figs 9-11 + ranking) into results/paper_grid/
	$(IMIX) run -m algo=snes env=continuous_cartpole popsize=10,25,50 sigma=0.05,0.1,0.25 lr=0.01,0.1 seeds=$(GRID_SEEDS) experiment=paper_grid $(SEC43)
	$(IMIX) plot experiment=paper_grid

reproduce-ddpg:  ## section 4.3: SNES + EIM (popsize 10, sigma 0.1, lr 0.1, 1500 generations) vs DDPG (Figs 12-13)
	$(IMIX) run -m algo=snes env=continuous_cartpole,continuous_cartpole_hard popsize=10 sigma=0.1 lr=0.1 generations=1500 experiment=paper_ddpg $(SEC43)
	$(IMIX) run algo=ddpg env=continuous_cartpole seeds=$(DDPG_SEEDS) experiment=paper_ddpg progress=false
	$(IMIX) run algo=ddpg env=continuous_cartpole_hard seeds=$(DDPG_HARD_SEEDS) experiment=paper_ddpg progress=false
	$(IMIX) plot experiment=paper_ddpg

reproduce-full:  ## the whole paper with 25 seeds everywhere
	$(MAKE) reproduce GRID_SEEDS=25 DDPG_SEEDS=25 DDPG_HARD_SEEDS=25

reproduce-quick:  ## the main figures from 3 seeds x 30 generations, in about a minute
	$(IMIX) run -m $(PAPER_GRID) experiment=quick seeds=3 generations=30 progress=false
	$(IMIX) plot experiment=quick

docs:  ## the documentation site into site/ (mkdocs-material + mkdocstrings: the docs extra, in install-all)
	@$(PY) -c "import mkdocs, mkdocstrings, material" 2>/dev/null || { echo 'make docs needs the docs extra: $(PY) -m pip install ".[docs]" (or make install-all)' >&2; exit 2; }
	$(PY) -m mkdocs build --strict

docs-numbers:  ## regenerate every printed output and figure the README and docs show (tests/test_docs.py checks them)
	$(PY) -m imix_cli.commands.docs_numbers write

bench:  ## speed benchmarks (rollouts, mixing, grid) with baselines measured in the same run
	$(IMIX) bench

# Beyond the paper (docs/research/mujoco.md): SNES and OpenES, without and with EIM, on Swimmer,
# Hopper and HalfCheetah (MuJoCo v5; needs the mujoco extra), MUJOCO_SEEDS seeds each. Linear
# policies on observations normalised with statistics frozen after a 3-generation warm-up
# (honest reuse). Each generation's fresh episodes, over all seeds in lockstep, run on every
# core (evaluator=pool). Budget: 12 runs x 5 seeds x 150 generations x 20 members, estimated
# at ~65-80 min on a quiet 2-core machine from the measured episode costs (see the docs file);
# finished runs are skipped, so an interrupted study resumes. Smoke test:
#   make reproduce-mujoco MUJOCO_SEEDS=2 MUJOCO_GENERATIONS=5 MUJOCO_EXPERIMENT=mujoco_smoke
MUJOCO_SEEDS       ?= 5
MUJOCO_GENERATIONS ?= 150
MUJOCO_POPSIZE     ?= 20
MUJOCO_EXPERIMENT  ?= mujoco
MUJOCO_GRID = algo=snes,openes env=swimmer,hopper,halfcheetah eim=false,true 'policy.hidden=[]' policy.obs_norm=true policy.obs_norm_warmup=3 sigma=0.1 lr=0.02 evaluator=pool

.PHONY: reproduce-mujoco
reproduce-mujoco:  ## MuJoCo study (SNES/OpenES x EIM x Swimmer/Hopper/HalfCheetah) + figures into results/mujoco/figures/
	$(IMIX) run -m $(MUJOCO_GRID) seeds=$(MUJOCO_SEEDS) generations=$(MUJOCO_GENERATIONS) popsize=$(MUJOCO_POPSIZE) experiment=$(MUJOCO_EXPERIMENT) progress=false
	$(PY) -m imix_cli.plotting.mujoco experiment=$(MUJOCO_EXPERIMENT)

# Reuse where overlap is small (docs/research/reuse_modes.md): SNES on MuJoCo without reuse, with exact mixing and
# with importance-weighted reuse (eim_variant=weighted), linear policies on HalfCheetah and Hopper, a 64x64 MLP on
# HalfCheetah (and, without reuse, at twice the learning rate), and ARS V2-t on Hopper with frozen and with updated
# observation statistics (policy.obs_norm_freeze), 10 seeds each; then the tables, into docs/research/reuse_modes.md.
# About 80 min on a 2-core machine; finished runs are skipped.
REUSE_MODES_SEEDS       ?= 10
REUSE_MODES_GENERATIONS ?= 100
REUSE_MODES_EXPERIMENT  ?= reuse_mujoco
REUSE_MODES_ARS = algo=ars env=hopper +ars=hopper policy.bias=true generations=100 eval_mean_every=5 eval_mean_episodes=3 seeds=$(REUSE_MODES_SEEDS) evaluator=pool progress=false experiment=ars_obsnorm
REUSE_MODES = algo=snes policy.obs_norm=true policy.obs_norm_warmup=3 sigma=0.1 lr=0.02 popsize=20 evaluator=pool seeds=$(REUSE_MODES_SEEDS) generations=$(REUSE_MODES_GENERATIONS) progress=false experiment=$(REUSE_MODES_EXPERIMENT)

.PHONY: reproduce-reuse-modes
reproduce-reuse-modes:  ## reuse modes on MuJoCo (none / exact / weighted; linear and 64x64) + tables (docs/research/reuse_modes.md)
	$(IMIX) run -m env=halfcheetah,hopper 'policy.hidden=[]' eim=false,true $(REUSE_MODES)
	$(IMIX) run -m env=halfcheetah,hopper 'policy.hidden=[]' eim=true eim_variant=weighted $(REUSE_MODES)
	$(IMIX) run -m env=halfcheetah 'policy.hidden=[64,64]' eim=false,true $(REUSE_MODES)
	$(IMIX) run -m env=halfcheetah 'policy.hidden=[64,64]' eim=true eim_variant=weighted $(REUSE_MODES)
	$(IMIX) run env=halfcheetah 'policy.hidden=[64,64]' eim=false $(REUSE_MODES) lr=0.04
	$(IMIX) run -m eim=false,true policy.obs_norm_freeze=true,false $(REUSE_MODES_ARS)
	$(IMIX) run -m eim=false policy.obs_norm_freeze=true,false $(REUSE_MODES_ARS) policy.bias=false
	$(PY) benchmarks/reuse_modes.py --experiment results/$(REUSE_MODES_EXPERIMENT) --experiment results/ars_obsnorm --page docs/research/reuse_modes.md

# Does reuse bend the search? (docs/research/bias.md) One table: every ES without mixing and with
# each rule (exact, conditional, exact + reeval_count=2), from constant fitness and pure noise to
# CartPole, Acrobot (25 seeds, the paper grid's runs) and SNES on Hopper and HalfCheetah (the
# MuJoCo study's settings). About 1 h on a quiet 2-core machine; finished runs are skipped.
REUSE_RULES_GRID = algo=openes,snes,cem,cmaes env=cartpole,acrobot eim=true
REUSE_MUJOCO = algo=snes env=hopper,halfcheetah 'policy.hidden=[]' policy.obs_norm=true policy.obs_norm_warmup=3 sigma=0.1 lr=0.02 evaluator=pool seeds=$(MUJOCO_SEEDS) generations=$(MUJOCO_GENERATIONS) popsize=$(MUJOCO_POPSIZE) progress=false

.PHONY: reuse-bias
reuse-bias:  ## the reuse-bias table (docs/research/bias.md) into results/reuse_bias/
	$(IMIX) run -m $(PAPER_GRID) experiment=paper progress=false
	$(IMIX) run -m $(REUSE_RULES_GRID) eim_variant=conditional experiment=reuse_rules progress=false
	$(IMIX) run -m $(REUSE_RULES_GRID) reeval_count=2 experiment=reuse_rules progress=false
	$(IMIX) run -m $(REUSE_MUJOCO) eim=false,true experiment=mujoco
	$(IMIX) run -m $(REUSE_MUJOCO) eim=true reeval_count=2 experiment=mujoco_rules
	mkdir -p results/reuse_bias
	for s in constant neutral noisy sphere; do $(PY) benchmarks/reuse_bias.py $$s --seeds 3 --generations 200 > results/reuse_bias/$$s.md; done
	$(PY) benchmarks/cma_step_size.py > results/reuse_bias/cma_step_size.md
	$(PY) benchmarks/cma_step_size.py --tasks cartpole,acrobot --task-seeds 25 > results/reuse_bias/cma_step_size_tasks.md
	$(PY) benchmarks/reuse_bias.py tasks --experiment results/paper --experiment results/reuse_rules > results/reuse_bias/tasks.md
	$(PY) benchmarks/reuse_bias.py tasks --experiment results/mujoco --experiment results/mujoco_rules > results/reuse_bias/mujoco.md

# ARS (docs/ars.md): Augmented Random Search with and without EIM (algo=ars, the ARS paper's
# settings per env: +ars=<env>) and sb3-contrib's ARS with rl-zoo3's settings (the ars extra), on
# Swimmer, Hopper and HalfCheetah v5, ARS_SEEDS seeds each, the same episode budget for all three:
# generations x 2N episodes (N = 1, 8, 32, 40 directions). The mean policy is measured on fresh
# episodes every ARS_EVAL_* generations (not counted as training episodes). Finished seeds are
# skipped. The defaults are rl-zoo3's budgets (2e6, ~7e6, ~1.25e7 env steps; Walker2d's 8,000 episodes
# are far below rl-zoo3's 7.5e7 steps): many hours here.
# docs/ars.md's reduced study used these budgets (Swimmer with 20 seeds, 10 with EIM; its commands are there):
#   make reproduce-ars ARS_SWIMMER_GENERATIONS=300 ARS_HOPPER_GENERATIONS=100 ARS_HALFCHEETAH_GENERATIONS=10 ARS_WALKER2D_GENERATIONS=20
ARS_SEEDS                   ?= 3
ARS_SWIMMER_GENERATIONS     ?= 1000
ARS_HOPPER_GENERATIONS      ?= 450
ARS_HALFCHEETAH_GENERATIONS ?= 200
ARS_WALKER2D_GENERATIONS    ?= 100
ARS_EXPERIMENT              ?= ars
ARS_COMMON = algo=ars eim=false,true seeds=$(ARS_SEEDS) eval_mean_episodes=3 experiment=$(ARS_EXPERIMENT) progress=false

.PHONY: reproduce-ars
reproduce-ars:  ## ARS study (imix ARS, ARS + EIM, sb3-contrib ARS on Swimmer/Hopper/HalfCheetah/Walker2d) + figures and table into results/ars/figures/
	$(IMIX) run -m env=swimmer +ars=swimmer generations=$(ARS_SWIMMER_GENERATIONS) eval_mean_every=10 $(ARS_COMMON)
	$(IMIX) run -m env=hopper +ars=hopper generations=$(ARS_HOPPER_GENERATIONS) eval_mean_every=5 $(ARS_COMMON)
	$(IMIX) run -m env=halfcheetah +ars=halfcheetah generations=$(ARS_HALFCHEETAH_GENERATIONS) eval_mean_every=1 $(ARS_COMMON)
	$(IMIX) run -m env=walker2d +ars=walker2d generations=$(ARS_WALKER2D_GENERATIONS) eval_mean_every=1 $(ARS_COMMON)
	$(PY) -m imix_cli.bench.ars_peer --envs swimmer --seeds $(ARS_SEEDS) --episodes $$((2 * $(ARS_SWIMMER_GENERATIONS))) --eval-every 10 --eval-episodes 3 --experiment $(ARS_EXPERIMENT)
	$(PY) -m imix_cli.bench.ars_peer --envs hopper --seeds $(ARS_SEEDS) --episodes $$((16 * $(ARS_HOPPER_GENERATIONS))) --eval-every 5 --eval-episodes 3 --experiment $(ARS_EXPERIMENT)
	$(PY) -m imix_cli.bench.ars_peer --envs halfcheetah --seeds $(ARS_SEEDS) --episodes $$((64 * $(ARS_HALFCHEETAH_GENERATIONS))) --eval-every 1 --eval-episodes 3 --experiment $(ARS_EXPERIMENT)
	$(PY) -m imix_cli.bench.ars_peer --envs walker2d --seeds $(ARS_SEEDS) --episodes $$((80 * $(ARS_WALKER2D_GENERATIONS))) --eval-every 1 --eval-episodes 3 --experiment $(ARS_EXPERIMENT)
	$(PY) -m imix_cli.plotting.ars experiment=$(ARS_EXPERIMENT)

# Reuse on tasks nobody tuned (docs/research/bias.md; benchmarks/untuned_tasks.py): every built-in ES without
# mixing and with the default EIM on six gymnasium tasks no preset covers (classic control and MuJoCo: the
# mujoco extra), population 20, 150 generations, 5 seeds; then the 100-episode evaluation and the table.
# Hours on a quiet 2-core machine; finished runs are skipped, so an interrupted benchmark resumes.
.PHONY: untuned
untuned:  ## the untuned-tasks benchmark (held-out tasks at default settings) into results/untuned/ and its table
	$(PY) benchmarks/untuned_tasks.py run
	$(PY) benchmarks/untuned_tasks.py table

# Mixing for pycma and evosax (docs/adapters.md; benchmarks/adapters.py): every table of that page, each
# section's markdown into results/adapters/. Needs the pycma and peers extras (pip install ".[pycma,peers]").
# Hours on a shared 2-core machine: pycma d = 40 (rosen, elli) and the noisy sphere's mixing arms dominate; the
# noisy budget is the one docs/adapters.md shows (3,000 evaluations).
ADAPTER_NOISY_BUDGET ?= 3000
.PHONY: adapters
# pycma alone and with mixing on COCO's bbob suite (docs/adapters.md, "COCO's bbob suite"; benchmarks/bbob.py): 24
# functions x d = 2, 5, 10 x instances 1-3, the arms of the table, COCO's observer data, cocopp's runtime ECDFs and
# the page's table and figures. Needs `pip install ".[bbob]"`. About 45 min of 2 cores for the runs (finished
# problems are skipped, so an interrupted run resumes), then ~10 min of cocopp.
BBOB_OUT  ?= results/bbob
BBOB_ARMS ?= pycma,mixing,mixing-pop2,pycma-pop2,mixing-pop3,pycma-pop3,pycma-ipop,mixing-ipop,pycma-bipop,mixing-bipop,mixing-cond,mixing-cond-pop2,mixing-tpa
bbob:  ## COCO's bbob suite: pycma alone and wrapped (table and cocopp figures of docs/adapters.md)
	$(PY) benchmarks/bbob.py run --out $(BBOB_OUT) --arms $(BBOB_ARMS)
	$(PY) benchmarks/bbob.py docs --out $(BBOB_OUT) --arms $(BBOB_ARMS)

# The same protocol on COCO's bbob-noisy suite (docs/adapters.md, "COCO's bbob-noisy suite"): functions 101-130 x d = 2,
# 5, 10 x instances 1-3 (270 problems), pycma alone, wrapped, and wrapped with reeval_count=2; a problem is hit when
# COCO's observer records a noise-free f - f_opt <= 1e-8. Needs `pip install ".[bbob]"`. 38 min in one process on a
# shared 2-core machine (the published run: d = 2 8 min, 5 14 min, 10 16 min; BBOB_NOISY_WORKERS=2 uses both cores),
# then 2 min of cocopp (offline: the reference data it draws ship with it). Finished problems are skipped.
BBOB_NOISY_OUT     ?= results/bbob-noisy
BBOB_NOISY_ARMS    ?= pycma,mixing,mixing-reeval2
BBOB_NOISY_WORKERS ?= 1
.PHONY: bbob-noisy
bbob-noisy:  ## COCO's bbob-noisy suite: pycma alone, wrapped and wrapped with reeval_count=2 (table and cocopp figures of docs/adapters.md)
	$(PY) benchmarks/bbob.py run --suite bbob-noisy --out $(BBOB_NOISY_OUT) --arms $(BBOB_NOISY_ARMS) --workers $(BBOB_NOISY_WORKERS)
	$(PY) benchmarks/bbob.py docs --suite bbob-noisy --out $(BBOB_NOISY_OUT) --arms $(BBOB_NOISY_ARMS)

adapters:  ## the tables of docs/adapters.md (pycma's test functions, the noisy sphere, evosax on gymnax CartPole) into results/adapters/
	mkdir -p results/adapters
	$(PY) benchmarks/adapters.py stepsize > results/adapters/stepsize.md
	$(PY) benchmarks/adapters.py cma --seeds 15 --dims 10,40 > results/adapters/cma.md
	$(PY) benchmarks/adapters.py noisy --seeds 15 --budget $(ADAPTER_NOISY_BUDGET) > results/adapters/noisy.md
	$(PY) benchmarks/adapters.py evosax --seeds 5 > results/adapters/evosax.md

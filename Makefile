# imix: the two set-up commands of the README, the paper reproduction and the benchmarks.
VENV   ?= .venv
PYTHON ?= python3
PY      = $(VENV)/bin/python
IMIX    = $(VENV)/bin/imix

# The paper's main grid (section 4.2): 4 ES x {CartPole, Acrobot} x {no mixing, EIM} x 25 seeds,
# each ES at its paper generation count. Finished runs are skipped, so an interrupted
# `make reproduce` continues where it stopped. The weight decay is the authors' code's form
# (estool: ranks - 0.05 mean(theta^2)): the paper's published curves come from it, while its
# text's -0.05|theta|^2 (the config default) keeps population scores far lower (README).
PAPER_GRID = algo=openes,snes,cem,cmaes env=cartpole,acrobot eim=false,true weight_decay_form=estool

.PHONY: install test reproduce reproduce-quick bench clean-quick

# torch for the DDPG baseline: the CPU build (on other machines, add
# --index-url https://download.pytorch.org/whl/cpu to avoid GBs of CUDA packages).
TORCH ?= torch==2.13.0

install:  ## create .venv and install imix (non-editable) with every extra
	$(PYTHON) -m venv $(VENV)
	$(PY) -m pip install --upgrade pip
	$(PY) -m pip install "$(TORCH)"
	$(PY) -m pip install ".[all]"

test:  ## run the test suite
	$(PY) -m pytest -q

reproduce:  ## the whole paper into results/paper/ (figures in results/paper/figures/)
	$(IMIX) run -m $(PAPER_GRID) experiment=paper progress=false
	$(IMIX) plot experiment=paper

reproduce-quick:  ## the same figures from 3 seeds x 30 generations, in about a minute
	$(IMIX) run -m $(PAPER_GRID) experiment=quick seeds=3 generations=30 progress=false
	$(IMIX) plot experiment=quick

bench:  ## speed benchmarks (rollouts, mixing, grid) with baselines measured in the same run
	$(IMIX) bench

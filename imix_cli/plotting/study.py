"""``imix plot`` of an Optuna search (``imix run -m hydra/sweeper=optuna``): the study's figures and its trials' table.

Drawn when the experiment's folder holds a study (``optuna.db``, :mod:`imix_cli.commands.search`) and the search extra
is installed, with Optuna's own matplotlib plots (the ones users know from Optuna's visualisation):

- ``study_history``: the optimisation history (each completed trial's value, the best so far; imix's own drawing, which
  marks the trials of objective=episodes where a seed never reached the threshold);
- ``study_importances``: the parameters' importances, by PED-ANOVA (Optuna's, no scikit-learn: the default fANOVA
  needs it, and the search extra does not install it);
- ``study_slice``: one slice plot per parameter (the value against the parameter, coloured by trial number);

and the table ``study_trials`` (CSV, Markdown, LaTeX: every trial, its state, value, parameters and run folder). Only
completed trials are plotted; failed ones (a killed search's, re-run since) are in the table with their state.

For objective=episodes a trial where some seed never reached the threshold holds a value above
:data:`imix_cli.running.objective.UNREACHED` (its ranking): the figures draw such trials at 1.1 times the largest value of
the trials where every seed reached it (the history marks them with crosses), so that the others stay readable.

The best trial's command line is printed (``imix plot: best trial ...: imix run ...``) to re-run it with more seeds.
"""

from __future__ import annotations

import warnings
from collections.abc import Iterator
from pathlib import Path

from imix_cli.commands.search import STUDY_FILE


def load_study(exp_path: Path):
    """(study, objective settings) of the experiment's study, or None (no study file, or no search extra: a warning)."""
    path = Path(exp_path) / STUDY_FILE
    if not path.is_file():
        return None
    try:
        import optuna
    except ImportError:
        from imix_cli.messages import install_extra

        raise RuntimeError(f"{path} holds an Optuna study; drawing it needs optuna ({install_extra('search')})") from None
    optuna.logging.set_verbosity(optuna.logging.WARNING)
    storage = optuna.storages.RDBStorage(f"sqlite:///{path.resolve()}")
    names = optuna.get_all_study_names(storage)
    studies = [optuna.load_study(study_name=name, storage=storage) for name in names]
    mine = [s for s in studies if "imix" in s.user_attrs]
    return mine[0] if len(mine) == 1 else (next((s for s in mine if s.study_name == Path(exp_path).name), mine[0]) if mine else None)


def _target(study):
    """The value each figure draws, its axis label, and whether a trial is drawn capped (objective=episodes: some seed
    never reached the threshold; module docstring)."""
    from imix_cli.running.objective import UNREACHED

    objective = study.user_attrs["imix"]["objective"]
    name = objective["objective"]
    if name != "episodes":
        label = {"theta": "θ's return on fresh episodes", "iqm": "θ's return (IQM over seeds)"}.get(name)
        return (lambda t: t.value), label or f"return at {objective.get('budget')} episodes", (lambda t: False)
    reached = [t.value for t in study.trials if t.value is not None and t.value < UNREACHED]
    cap = 1.1 * max(reached) if reached else 1.0
    unreached = lambda t: t.value >= UNREACHED  # noqa: E731
    return (lambda t: cap if unreached(t) else t.value), f"episodes to {objective.get('threshold'):g} (mean over seeds)", unreached


def _history(study, done, target, label, capped):
    """The optimisation history: each completed trial's value by trial number, the best so far as a step line; trials
    drawn capped (a seed never reached the threshold) as crosses at the top."""
    from matplotlib.figure import Figure

    maximize = study.direction.name == "MAXIMIZE"
    fig = Figure(figsize=(6.4, 4.0))
    ax = fig.add_subplot()
    numbers = [t.number for t in done]
    values = [target(t) for t in done]
    plain = [(n, v) for n, v, t in zip(numbers, values, done) if not capped(t)]
    if plain:
        ax.scatter(*zip(*plain), color="#0072B2", s=22, zorder=3, label="trial")
    top = [(n, v) for n, v, t in zip(numbers, values, done) if capped(t)]
    if top:
        ax.scatter(*zip(*top), marker="x", color="#D55E00", s=28, zorder=3, label="some seed never reached it (ranked below)")
    best, running = [], None
    for t in done:
        running = t.value if running is None else (max(running, t.value) if maximize else min(running, t.value))
        best.append(target(type("T", (), {"value": running})()))
    ax.step(numbers, best, where="post", color="#009E73", label="best so far")
    from matplotlib.ticker import MaxNLocator

    ax.xaxis.set_major_locator(MaxNLocator(integer=True))
    ax.set_xlabel("trial")
    ax.set_ylabel(label)
    ax.set_title(f"study {study.study_name}: {len(done)} completed trials", fontsize=10)
    ax.legend(fontsize=8, loc="best")
    fig.tight_layout()
    return fig


def study_figures(exp, opts) -> Iterator:
    """The study's figures (module docstring), after printing the best trial's command line."""
    study = load_study(exp.path)
    if study is None:
        return
    import matplotlib.pyplot as plt
    import optuna
    from optuna.trial import TrialState
    from optuna.visualization import matplotlib as ovm

    from imix_cli.commands.search import best_command

    done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not done:
        opts.warn(f"study {study.study_name!r} in {exp.path / STUDY_FILE} has no completed trial yet: nothing to draw")
        return
    best = study.best_trial
    command = best_command(study, best)
    print(f"imix plot: best trial of study {study.study_name!r}: trial {best.number} ({best.value:.6g}), re-run it with more seeds: {command}")
    target, label, capped = _target(study)
    yield "study_history", _history(study, done, target, label, capped)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        warnings.filterwarnings("ignore", message=".*PedAnova.*")
        if len(done) >= 2 and len(best.params) >= 1:
            evaluator = optuna.importance.PedAnovaImportanceEvaluator()
            ax = ovm.plot_param_importances(study, evaluator=evaluator, target=target, target_name=label)
            yield "study_importances", _figure(ax)
        ax = ovm.plot_slice(study, target=target, target_name=label)
        yield "study_slice", _figure(ax)
    plt.close("all")


def _figure(axes):
    """The Figure of Optuna's axes; a slice plot's (one axes per parameter, and a colour bar) widened, not re-laid out."""
    import numpy as np

    if isinstance(axes, np.ndarray):
        fig = axes.flat[0].figure
        fig.set_size_inches(4.5 * axes.size + 1.5, 4.5)
        return fig
    fig = axes.figure
    fig.set_size_inches(max(fig.get_size_inches()[0], 6.4), max(fig.get_size_inches()[1], 4.0))
    fig.tight_layout()
    return fig

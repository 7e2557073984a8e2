"""``imix run -m hydra/sweeper=optuna ...``: a hyper-parameter search with Optuna's ask/tell API, stored in a database.

The Hydra plugin (``hydra_plugins/imix_optuna_sweeper``) hands its work to :class:`Search`: the command line's search
space (:mod:`imix_cli.running.config.search`) becomes Optuna distributions, each trial is one imix run launched by Hydra's
launcher (its ``seeds`` seeds; the basic launcher runs it in this process, ``hydra/launcher=joblib`` several at once),
and the task function returns the run's objective (:func:`trial_result`, :mod:`imix_cli.running.objective`).

The study
    is kept in ``<results_dir>/<experiment>/optuna.db`` (SQLite, through Optuna's RDBStorage) or the database of
    ``hydra.sweeper.storage`` (``postgresql://...`` for searches on several machines), named after the experiment
    (``hydra.sweeper.study_name``). The search space, the fixed overrides and the objective are stored with it: a
    command that differs (another space, objective or seeds) is refused in one line rather than mixed into it.

Resuming
    Re-running the same command continues the study until it holds ``n_trials`` finished (completed or pruned) trials. A trial left
    RUNNING by a search that was killed (``kill -9``, a power cut) is found -- on this machine by its process id,
    which is no longer alive; on another, by its heartbeat (recorded every :data:`HEARTBEAT_SECONDS`, stale after
    :data:`GRACE_SECONDS`) -- marked FAIL (Optuna's state for a trial that will not finish; its user attribute
    ``imix_stale`` says why) and enqueued again with the same parameters (``imix_retry_of``: its number), so that it
    is run once more, in the same run folder, where its seeds resume from their checkpoints. A FAIL trial never counts
    towards ``n_trials``; a retried one counts once, when it completes. Trials RUNNING in a live search (the same study
    from another process) are left alone and count as under way.

Pruning
    With ``hydra.sweeper.pruner=median`` a trial's run is made in stages (:data:`imix_cli.running.config.search.PRUNING_STAGES`
    of its generations; a continued run is exactly the run made at once), its objective reported to Optuna's
    MedianPruner after each but the last; a pruned trial's run folder gets a PRUNED file
    (:data:`imix_cli.running.files.results.PRUNED_FILE`) and ``imix plot`` leaves it out.

Each trial records its run folder (``run_dir``), its per-seed values and the process that ran it as user attributes.
Two trials with the same parameters share a run folder (the same config: its finished seeds are not run again).
"""

from __future__ import annotations

import os
import socket
import sys
import threading
from pathlib import Path

from imix_cli.messages import bounded_line
from imix_cli.running.config.compose import override_value_text
from imix_cli.running.config.search import OBJECTIVES, SWEEPER_TARGET, is_search

#: An Optuna trial's heartbeat period and the silence after which another machine's RUNNING trial is stale.
HEARTBEAT_SECONDS = 30
GRACE_SECONDS = 120
#: The database file of a study stored under its experiment's folder.
STUDY_FILE = "optuna.db"
#: Task overrides that do not change a trial's result (how the seeds run, where results go): a resumed search may differ in these.
_HOW_ONLY = ("progress", "workers", "evaluator", "evaluator_workers", "ray_address", "checkpoint_every", "checkpoint_seconds", "logger", "results_dir")


class SearchError(RuntimeError):
    """A search that cannot start or go on (one line)."""


def say(message: str) -> None:
    print(bounded_line(f"imix search: {message}"), flush=True)


def default_storage(experiment_dir: Path) -> str:
    return f"sqlite:///{Path(os.path.abspath(experiment_dir)) / STUDY_FILE}"


def make_storage(url: str):
    """Optuna's RDBStorage on ``url``, with heartbeats (how another machine's killed trial is found)."""
    import optuna

    return optuna.storages.RDBStorage(url, heartbeat_interval=HEARTBEAT_SECONDS, grace_period=GRACE_SECONDS)


def mark_pruned(run_dir: Path, number: int, study_name: str, generations: int) -> None:
    """Write the run folder's PRUNED file (:data:`imix_cli.running.files.results.PRUNED_FILE`): what stopped it, where."""
    from imix_cli.running.files.results import PRUNED_FILE
    from imix_cli.running.files.writing import atomic_write_text

    text = (f"trial {number} of the Optuna study {study_name!r} was pruned at generation {generations}: the seeds' CSVs here stop there "
            "(partial results of a trial stopped early, left out of imix plot); a later trial with the same parameters continues them\n")  # fmt: skip
    atomic_write_text(run_dir / PRUNED_FILE, text, root=run_dir.parent.parent)


def unmark_pruned(run_dir: Path) -> None:
    from imix_cli.running.files.results import PRUNED_FILE

    try:
        (run_dir / PRUNED_FILE).unlink()
    except FileNotFoundError:
        pass


def make_pruner(name: str):
    import optuna

    return optuna.pruners.MedianPruner() if name == "median" else optuna.pruners.NopPruner()


def make_sampler(name: str, seed):
    import optuna

    if name == "cmaes":
        return optuna.samplers.CmaEsSampler(seed=seed, warn_independent_sampling=False)
    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    return optuna.samplers.TPESampler(seed=seed)


def distribution(override):
    """The Optuna distribution of one search-space override (already checked: :func:`imix_cli.running.config.search.probe_values`)."""
    from hydra.core.override_parser.types import ChoiceSweep, IntervalSweep, RangeSweep
    from optuna.distributions import CategoricalDistribution, FloatDistribution, IntDistribution

    value = override.value()
    if isinstance(value, ChoiceSweep):
        return CategoricalDistribution(list(value.list))
    if isinstance(value, RangeSweep):
        values = list(override.sweep_iterator())
        if all(isinstance(v, int) for v in values) and isinstance(value.step, int):
            return IntDistribution(values[0], values[-1], step=value.step) if len(values) > 1 else CategoricalDistribution(values)
        return CategoricalDistribution(values)
    assert isinstance(value, IntervalSweep)
    log = "log" in value.tags
    if "int" in value.tags:
        return IntDistribution(int(value.start), int(value.end), log=log)
    return FloatDistribution(float(value.start), float(value.end), log=log)


def split_arguments(arguments: list[str], config_loader=None) -> tuple[list[str], dict]:
    """The command line's task overrides -> (the fixed ones, as given; search-space key -> Optuna distribution)."""
    from hydra.core.override_parser.overrides_parser import OverridesParser

    parser = OverridesParser.create(config_loader=config_loader)
    fixed, space = [], {}
    for override in parser.parse_overrides(arguments):
        if override.is_sweep_override():
            space[override.get_key_element()] = distribution(override)
        else:
            fixed.append(override.input_line)
    if not space:
        raise SearchError("hydra/sweeper=optuna: no search space; give one, e.g. sigma=interval(0.01,0.5) popsize=choice(10,20,50)")
    return fixed, space


def study_identity(fixed: list[str], space: dict, settings: dict) -> dict:
    """What a study was made for: the fixed overrides that change results, the search space and the objective."""
    from optuna.distributions import distribution_to_json

    kept = sorted(line for line in fixed if line.split("=", 1)[0].lstrip("+~") not in _HOW_ONLY)
    objective = {k: settings.get(k) for k in ("objective", "threshold", "budget")}
    return {"fixed": kept, "space": {k: distribution_to_json(d) for k, d in sorted(space.items())}, "objective": objective}


def open_study(settings: dict, experiment_dir: Path, experiment: str, identity: dict):
    """Create or load the study; SearchError if a stored study was made for another search."""
    import optuna

    url = settings.get("storage") or default_storage(experiment_dir)
    if not settings.get("storage"):
        experiment_dir.mkdir(parents=True, exist_ok=True)
    name = settings.get("study_name") or experiment
    direction = OBJECTIVES[settings["objective"]]
    storage = make_storage(url)
    study = optuna.create_study(study_name=name, storage=storage, sampler=make_sampler(settings["sampler"], settings.get("seed")),
                                pruner=make_pruner(settings.get("pruner", "none")), direction=direction, load_if_exists=True)  # fmt: skip
    stored = study.user_attrs.get("imix")
    if stored is None:
        if study.trials:
            raise SearchError(f"study {name!r} in {url} holds trials of another program; choose hydra.sweeper.study_name=")
        study.set_user_attr("imix", identity)
    elif stored != identity:
        what = next(k for k in ("objective", "space", "fixed") if stored.get(k) != identity.get(k))
        raise SearchError(
            f"study {name!r} in {url} was made with another {'search space' if what == 'space' else what} "
            f"({_short(stored.get(what))}); re-run its own command to resume it, or give another experiment= (or hydra.sweeper.study_name=)"
        )
    return study, storage, url


def _short(value) -> str:
    text = str(value)
    return text if len(text) <= 200 else text[:200] + "..."


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    except OSError:
        return False
    return True


def recover_stale_trials(study, storage) -> list[int]:
    """Mark the trials a killed search left RUNNING as FAIL and enqueue each again with its parameters; return their numbers."""
    import optuna
    from optuna.trial import TrialState

    host = socket.gethostname()
    # Optuna's own test of a silent trial (BaseHeartbeat; study.optimize uses it through fail_stale_trials)
    stale_ids = set(storage._get_stale_trial_ids(study._study_id)) if storage.get_heartbeat_interval() else set()
    recovered = []
    for trial in study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)):
        attrs = trial.user_attrs
        mine = attrs.get("host") == host and isinstance(attrs.get("pid"), int)
        if mine and _pid_alive(attrs["pid"]):
            continue  # a live search on this machine
        if not mine and trial._trial_id not in stale_ids:
            continue  # another machine's, still beating (or not yet silent for GRACE_SECONDS)
        why = f"its process {attrs.get('pid')} on {host} is gone" if mine else f"no heartbeat for {GRACE_SECONDS} s"
        trial_id = trial._trial_id
        try:
            storage.set_trial_user_attr(trial_id, "imix_stale", f"left RUNNING by a killed search ({why}); re-run as a new trial")
            if not storage.set_trial_state_values(trial_id, state=TrialState.FAIL):
                continue
        except optuna.exceptions.UpdateFinishedTrialError:
            continue  # another search marked it first (and enqueued its retry)
        study.enqueue_trial(dict(trial.params), user_attrs={"imix_retry_of": trial.number}, skip_if_exists=False)
        recovered.append(trial.number)
    return recovered


class _Heartbeat:
    """Records the heartbeat of the trials under way every :data:`HEARTBEAT_SECONDS` (a daemon thread)."""

    def __init__(self, storage, trial_ids: list[int]):
        self.storage, self.trial_ids, self.stop = storage, trial_ids, threading.Event()
        self.thread = threading.Thread(target=self._beat, daemon=True)

    def _beat(self) -> None:
        while True:
            for trial_id in self.trial_ids:
                try:
                    self.storage.record_heartbeat(trial_id)
                except Exception:  # noqa: BLE001 - a missed beat is not a failed trial
                    pass
            if self.stop.wait(HEARTBEAT_SECONDS):
                return

    def __enter__(self):
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=5)


def trial_result(spec, sweeper) -> dict:
    """What the task function returns to the search for ``spec``'s finished run: the objective's value and where it came from."""
    from imix_cli.running.objective import ObjectiveError, objective_value

    try:
        value, details = objective_value(spec.run_dir, spec.seeds, sweeper["objective"], sweeper.get("threshold"), sweeper.get("budget"))
    except ObjectiveError as err:
        return {"error": str(err), "run_dir": str(spec.run_dir)}
    return {"value": value, "run_dir": str(spec.run_dir), **details}


def search_settings_of(hydra_config) -> dict | None:
    """The ``hydra.sweeper`` settings of a job if the search is imix's Optuna sweeper, else None."""
    from omegaconf import OmegaConf

    sweeper = OmegaConf.select(hydra_config, "sweeper")
    if sweeper is None or not is_search(OmegaConf.select(sweeper, "_target_")):
        return None
    return OmegaConf.to_container(sweeper, resolve=True)


class Search:
    """One ``imix run -m hydra/sweeper=optuna`` search: see the module's docstring."""

    def __init__(self, settings: dict, hydra_context, task_function, config):
        from hydra.core.plugins import Plugins

        from imix_cli.running.config.search import check_search_settings

        self.settings = check_search_settings({"_target_": SWEEPER_TARGET, **settings})
        self.hydra_context, self.config = hydra_context, config
        self.launcher = Plugins.instance().instantiate_launcher(hydra_context=hydra_context, task_function=task_function, config=config)

    def sweep(self, arguments: list[str]) -> list:
        try:
            return self._sweep(arguments)
        except SearchError as err:
            print(bounded_line(f"imix run: error: {err}"), file=sys.stderr, flush=True)
            sys.exit(2)

    def _sweep(self, arguments: list[str]) -> list:
        import warnings

        import optuna
        from omegaconf import OmegaConf
        from optuna.trial import TrialState

        optuna.logging.set_verbosity(optuna.logging.WARNING)
        warnings.filterwarnings("ignore", category=optuna.exceptions.ExperimentalWarning)
        # ask/tell with heartbeats: imix records them itself (_Heartbeat), which Optuna's warning does not know
        warnings.filterwarnings("ignore", message="Heartbeat of storage is supposed to be used with Study.optimize")
        fixed, space = split_arguments(arguments, self.hydra_context.config_loader)
        composed = self.hydra_context.config_loader.load_sweep_config(master_config=self.config, sweep_overrides=list(fixed))
        results_dir, experiment = OmegaConf.select(composed, "results_dir"), OmegaConf.select(composed, "experiment")
        experiment_dir = Path(str(results_dir)) / str(experiment)
        study, storage, url = open_study(self.settings, experiment_dir, str(experiment), study_identity(fixed, space, self.settings))
        n_trials, n_jobs = self.settings["n_trials"], self.settings["n_jobs"]
        stages = self._stages(composed, space)
        recovered = recover_stale_trials(study, storage)
        if recovered:
            which = f"trial {recovered[0]} was" if len(recovered) == 1 else f"trials {', '.join(map(str, recovered))} were"
            say(f"{which} left running by a killed search: marked FAIL and run again with the same parameters")
        # finished trials: completed, and pruned ones (a pruner spends the trials it stops early on others)
        complete = lambda: len(study.get_trials(deepcopy=False, states=(TrialState.COMPLETE, TrialState.PRUNED)))  # noqa: E731
        say(f"study {study.study_name!r} in {url}: {complete()} of {n_trials} trials completed; objective {self._objective_text()}")
        returns, job, failures, host = [], 0, 0, socket.gethostname()
        while True:
            under_way = len(study.get_trials(deepcopy=False, states=(TrialState.RUNNING,)))  # other searches' trials
            todo = n_trials - complete() - under_way
            if todo <= 0:
                break
            trials = [study.ask(space) for _ in range(min(n_jobs, todo))]
            for trial in trials:
                trial.set_user_attr("host", host)
                trial.set_user_attr("pid", os.getpid())
            for generations in stages:  # one stage (the run) without a pruner
                last = generations == stages[-1]
                # a re-run trial (its folder may hold seeds beyond the early stages, which a run never shortens) runs its last stage only
                now = [t for t in trials if last or "imix_retry_of" not in t.user_attrs]
                if not now:
                    continue
                base = fixed if generations is None else [*(f for f in fixed if f.split("=", 1)[0] != "generations"), f"generations={generations}"]
                batch = [[*base, *(f"{k}={override_value_text(v)}" for k, v in trial.params.items())] for trial in now]
                with _Heartbeat(storage, [t._trial_id for t in trials]):
                    try:
                        results = self.launcher.launch(batch, initial_job_idx=job)
                    except BaseException:
                        for trial in trials:  # a Ctrl-C, SIGTERM, a failed launch: these trials will not finish here; the next search re-runs them
                            _tell_failed(study, trial, "the search stopped during the trial", retry=True)
                        raise
                job += len(batch)
                returns.append(results)
                stopped = set()
                for trial, result in zip(now, results):
                    told = self._tell(study, trial, result) if last else self._report_stage(study, trial, result, generations)
                    failures += told is False
                    stopped |= set() if told is None else {trial.number}
                trials = [t for t in trials if t.number not in stopped]
                if not trials:
                    break
            if failures >= n_trials:
                raise SearchError(f"{failures} trials failed in this search (see the lines above); stopping")
        self._report(study)
        return returns

    def _stages(self, composed, space: dict) -> list:
        """The generations each trial's run is made in: ``[None]`` (its own) without a pruner; with one, the fractions
        :data:`~imix_cli.running.config.search.PRUNING_STAGES` of ``generations``."""
        from omegaconf import OmegaConf

        from imix_cli.running.config.search import PRUNING_STAGES

        if self.settings.get("pruner", "none") == "none":
            return [None]
        if "generations" in space:
            raise SearchError("hydra.sweeper.pruner: a search over generations cannot be pruned (the pruner runs each trial in stages of its generations)")
        total = int(OmegaConf.select(composed, "generations"))
        return sorted({max(1, round(total * f)) for f in PRUNING_STAGES})

    def _report_stage(self, study, trial, result, generations: int):
        """A stage short of the trial's ``generations``: its objective reported to the pruner; True if the trial is
        pruned (told PRUNED, its run folder marked), None if it goes on, False if it failed."""
        from optuna.trial import TrialState

        returned, why = _returned(study, trial, result)
        if why is not None:
            return _failed(study, trial, why)
        trial.report(returned["value"], step=generations)
        if not trial.should_prune():
            return None
        mark_pruned(Path(returned["run_dir"]), trial.number, study.study_name, generations)
        trial.set_user_attr("run_dir", returned["run_dir"])
        trial.set_user_attr("pruned_at_generation", generations)
        study.tell(trial, state=TrialState.PRUNED)
        say(f"trial {trial.number} pruned at generation {generations}: {self._value_text(returned)} (its run folder is marked PRUNED)")
        return True

    def _objective_text(self) -> str:
        s = self.settings
        extra = f" to {s['threshold']:g}" if s["objective"] == "episodes" else (f" at {s['budget']} episodes" if s["objective"] == "return_at" else "")
        return f"{s['objective']}{extra} ({OBJECTIVES[s['objective']]}d)"

    def _tell(self, study, trial, result) -> bool:
        returned, why = _returned(study, trial, result)
        if why is not None:
            if isinstance(returned, dict) and returned.get("run_dir"):
                trial.set_user_attr("run_dir", returned["run_dir"])
            return _failed(study, trial, why)
        for key, value in returned.items():
            if key != "value":
                trial.set_user_attr(key, value)
        unmark_pruned(Path(returned["run_dir"]))  # a completed run in a folder an earlier trial with these parameters left pruned
        study.tell(trial, returned["value"])
        params = ", ".join(f"{k}={override_value_text(v)}" for k, v in trial.params.items())
        say(f"trial {trial.number}: {self._value_text(returned)}  ({params})")
        return True

    def _value_text(self, returned: dict) -> str:
        if self.settings["objective"] == "episodes":
            reached, seeds = returned.get("seeds_reached"), len(returned.get("per_seed", ()))
            if reached == seeds:
                return f"{returned['value']:.1f} episodes to {self.settings['threshold']:g} ({reached}/{seeds} seeds)"
            return f"{reached}/{seeds} seeds reached {self.settings['threshold']:g} (ranked below every trial where more did)"
        return f"{self.settings['objective']} {returned['value']:.3f}"

    def _report(self, study) -> None:
        from optuna.trial import TrialState

        done = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
        pruned = len(study.get_trials(deepcopy=False, states=(TrialState.PRUNED,)))
        if not done:
            return
        best = study.best_trial
        also = f", {pruned} pruned" if pruned else ""
        say(f"{len(done)} trials completed{also}; best: trial {best.number}, {self._value_text({'value': best.value, **best.user_attrs})}")
        say(f"re-run it with more seeds: {best_command(study, best)}")


def _returned(study, trial, result) -> tuple:
    """``(what the trial's run returned, why it has no value or None)``; a run that raised is told FAIL and re-raised."""
    try:
        returned = result.return_value
    except BaseException:
        _tell_failed(study, trial, "the run raised an error")
        raise
    if isinstance(returned, dict) and "value" in returned:
        return returned, None
    return returned, (returned.get("error") if isinstance(returned, dict) else "the run did not finish (see the lines above)")


def _failed(study, trial, why: str) -> bool:
    """Tell ``trial`` FAIL and say why; False (the trial gave no value)."""
    _tell_failed(study, trial, why)
    say(f"trial {trial.number} failed: {why}")
    return False


def _tell_failed(study, trial, why: str, retry: bool = False) -> None:
    """Tell ``trial`` FAIL (``why`` in its user attribute ``imix_failed``); ``retry``: a search stopped during it (Ctrl-C,
    SIGTERM), so its parameters are enqueued to run again (``imix_retry_of``), as a killed search's are on resuming."""
    from optuna.trial import TrialState

    try:
        trial.set_user_attr("imix_failed", why)
        study.tell(trial, state=TrialState.FAIL)
    except Exception:  # noqa: BLE001 - already finished (told by another path)
        return
    if retry:
        study.enqueue_trial(dict(trial.params), user_attrs={"imix_retry_of": trial.number}, skip_if_exists=False)


def best_command(study, trial) -> str:
    """``imix run ...`` of a trial: the study's fixed overrides (those that change results) and the trial's parameters."""
    fixed = study.user_attrs.get("imix", {}).get("fixed", [])
    fixed = [line for line in fixed if line.split("=", 1)[0] not in ("seeds", "experiment")]
    params = [f"{k}={override_value_text(v)}" for k, v in trial.params.items()]
    return " ".join(["imix run", *fixed, *params, "seeds=10", f"experiment={study.study_name}-best"])

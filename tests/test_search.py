"""``imix run -m hydra/sweeper=optuna``: imix's Optuna sweeper, with real Optuna and a real SQLite study (no mocks).

A tiny search (SNES on CartPole, 2 seeds of a few generations: seconds a trial) checks the study, each trial's value
against its run's CSVs and its run folder; a search killed with SIGKILL in the middle of a trial is resumed with no trial
lost or counted twice; a typo is one line and exit status 2 before any trial; ``imix plot`` draws the study.
"""

import contextlib
import math
import os
import signal
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import extra_installed

from imix_cli.commands.cli import main
from imix_cli.running.files.results import read_run_csv, rows_to_frame, write_run_csv

pytestmark = pytest.mark.search

if extra_installed("search"):
    import optuna

ROOT = Path(__file__).resolve().parents[1]
TINY = ["algo=snes", "env=cartpole", "seeds=2", "generations=10", "eval_mean_every=5", "progress=false", "workers=1"]
SPACE = ["sigma=interval(0.05,0.5)", "popsize=choice(8,12)", "lr=tag(log, interval(1e-3,1e-1))"]


def study_of(results: Path, experiment: str):
    storage = optuna.storages.RDBStorage(f"sqlite:///{results / experiment / 'optuna.db'}")
    return optuna.load_study(study_name=experiment, storage=storage)


def states(study) -> dict:
    out: dict = {}
    for t in study.get_trials(deepcopy=False):
        out.setdefault(t.state.name, []).append(t.number)
    return out


def test_a_tiny_search_stores_its_trials_and_their_runs_in_sqlite(tmp_path, capsys):
    """Made to fail: with objective theta's direction set to minimize (OBJECTIVES), the direction assertion failed."""
    args = ["run", "-m", "hydra/sweeper=optuna", *TINY, *SPACE, "hydra.sweeper.n_trials=3", "hydra.sweeper.seed=1", f"results_dir={tmp_path}", "experiment=s"]
    assert main(args) == 0
    out = capsys.readouterr().out
    study = study_of(tmp_path, "s")
    assert study.direction == optuna.study.StudyDirection.MAXIMIZE
    complete = study.get_trials(states=(optuna.trial.TrialState.COMPLETE,))
    assert len(complete) == len(study.trials) == 3
    run_dirs = set()
    for trial in complete:
        run_dir = Path(trial.user_attrs["run_dir"])
        assert run_dir.parent == tmp_path / "s" and run_dir.is_dir()
        run_dirs.add(run_dir)
        thetas = []
        for seed in range(2):
            frame = read_run_csv(run_dir / f"seed_{seed}.csv")
            assert len(frame) == 10 and int(frame["popsize"].iloc[0]) == trial.params["popsize"]
            measured = frame["mean_policy_score"].to_numpy(dtype=float)
            thetas.append(measured[np.isfinite(measured)][-1])
        assert trial.value == pytest.approx(np.mean(thetas))
        assert 0.05 <= trial.params["sigma"] <= 0.5 and 1e-3 <= trial.params["lr"] <= 1e-1
        assert f"sigma={trial.params['sigma']!r}" in run_dir.name
    assert len(run_dirs) == 3  # each trial its own run folder
    assert "re-run it with more seeds: imix run algo=snes" in out
    # the same command again: the study holds its 3 trials, nothing runs
    assert main(args) == 0
    assert len(study_of(tmp_path, "s").trials) == 3
    # n_trials raised: the search goes on from the stored trials
    assert main([*args[:-2], "hydra.sweeper.n_trials=4", *args[-2:]]) == 0
    assert len(study_of(tmp_path, "s").get_trials(states=(optuna.trial.TrialState.COMPLETE,))) == 4


@pytest.mark.parametrize(
    ("extra", "said"),
    [
        (["sigmaa=interval(0.05,0.5)"], "unknown key 'sigmaa'; did you mean 'sigma'?"),
        (["sigma=interval(-1,0.5)"], "sigma=-1.0: must be > 0"),
        (["popsize=interval(8,50)"], "must be an integer >= 2 (a value of the search space popsize=interval(8,50))"),
        ([*SPACE, "hydra.sweeper.n_trails=3"], "unknown key hydra.sweeper.n_trails; valid keys of hydra/sweeper=optuna"),
        ([*SPACE, "hydra.sweeper.objective=episodes"], "objective=episodes needs the return that counts as reached"),
        ([*SPACE, "hydra.sweeper.sampler=grid"], "hydra.sweeper.sampler='grid': must be one of tpe, cmaes, random"),
        ([*SPACE, "eval_mean_every=0"], "eval_mean_every must be > 0"),
    ],
)
def test_a_typo_is_one_line_and_exit_2_before_any_trial(extra, said, tmp_path, capsys):
    """Made to fail: with validate_overrides no longer probing search spaces (uses_search_sweeper returning False), every
    case failed (the interval refused as a sweep -m cannot enumerate, or the bad value found only by a trial)."""
    status = main(["run", "-m", "hydra/sweeper=optuna", *TINY, *extra, "hydra.sweeper.n_trials=2", f"results_dir={tmp_path}"])
    err = capsys.readouterr().err.strip()
    assert status == 2, err
    assert len(err.splitlines()) == 1 and said in err, err
    assert not any(tmp_path.iterdir())  # no study, no run folder


def test_a_study_made_for_another_search_is_refused_before_any_trial(tmp_path, capsys):
    base = ["run", "-m", "hydra/sweeper=optuna", *TINY, "hydra.sweeper.n_trials=1", f"results_dir={tmp_path}", "experiment=s"]
    assert main([*base, "sigma=interval(0.05,0.5)"]) == 0
    capsys.readouterr()
    assert main([*base, "sigma=interval(0.05,0.4)"]) == 2
    err = capsys.readouterr().err.strip()
    assert err.splitlines()[-1].startswith("imix run: error: study 's'") and "another search space" in err, err
    assert len(study_of(tmp_path, "s").trials) == 1


def _frame(scores, evaluations, seed=0, thetas=None):
    rows = []
    for g, (score, spent) in enumerate(zip(scores, evaluations)):
        rows.append({"algo": "snes", "env": "cartpole", "mixing": "none", "seed": seed, "generation": g, "evaluations": spent, "env_steps": spent * 10,
                     "mean_score": score, "best_score": score, "reused": 0, "reused_im": 0, "reused_eim": 0, "popsize": 10, "sigma_mean": 0.1,
                     "nonfinite": 0, "wall_time": 0.0, "mean_policy_score": (thetas or [math.nan] * len(scores))[g]})  # fmt: skip
    return rows_to_frame(rows)


def test_episodes_rank_a_run_that_never_reaches_the_threshold_below_every_run_that_does(tmp_path):
    """Episodes and return_at read θ on fresh episodes, not the population (here stuck at -500 while θ progresses; and
    a population at 0, above the threshold, whose θ never gets there). Made to fail: with UNREACHED set to 0 (a seed that
    never reaches counts only the episodes it spent), the run that never reached the threshold in 30 episodes ranked
    better than the one that reached it in 200; with episodes read from mean_score, no run reached it."""
    from imix_cli.running.objective import UNREACHED, objective_value

    def run(name, seeds, population=-500.0):
        folder = tmp_path / name
        folder.mkdir()
        for seed, (thetas, spent) in enumerate(seeds):
            write_run_csv(folder / f"seed_{seed}.csv", _frame([population] * len(thetas), spent, seed, thetas=list(thetas)))
        return objective_value(folder, len(seeds), "episodes", threshold=-100)

    slow, slow_details = run("slow", [([-200, -150, -90], [100, 200, 300]), ([-200, -99, -80], [100, 200, 300])])
    assert slow == pytest.approx(250.0) and slow_details["seeds_reached"] == 2
    never, never_details = run("never", [([-200, -150, -110], [10, 20, 30]), ([-200, -50, -40], [10, 20, 30])])
    assert never_details["seeds_reached"] == 1 and never > slow and never >= UNREACHED
    worse, _ = run("worse", [([-200, -150, -110], [10, 20, 30]), ([-200, -150, -110], [10, 20, 30])])
    assert worse > never  # two seeds never reaching it rank below one
    budget, _ = objective_value(tmp_path / "slow", 2, "return_at", budget=250)
    assert budget == pytest.approx((-150 + -99) / 2)
    flattered, details = run("flattered", [([-200, -150, -110], [10, 20, 30])], population=0.0)
    assert details["seeds_reached"] == 0 and flattered >= UNREACHED  # the population's 0 is not θ reaching -100


def _search_command(results: Path, n_trials: int) -> list:
    return [sys.executable, "-m", "imix_cli.commands.cli", "run", "-m", "hydra/sweeper=optuna", "algo=snes", "env=cartpole", "seeds=2", "generations=2000",
            "eval_mean_every=100", "progress=false", "workers=1", "checkpoint_every=20", "checkpoint_seconds=0", *SPACE,
            f"hydra.sweeper.n_trials={n_trials}", "hydra.sweeper.seed=3", f"results_dir={results}", "experiment=k"]  # fmt: skip


def _states_read_only(db: Path) -> dict:
    """Trial numbers by state, read from the study's SQLite file opened read-only: a poll through Optuna's storage
    would create the schema itself if it came before the search's, racing the search for it."""
    import sqlite3

    if not db.exists():
        return {}
    try:
        with contextlib.closing(sqlite3.connect(f"file:{db}?mode=ro", uri=True, timeout=1)) as connection:
            rows = connection.execute("SELECT number, state FROM trials").fetchall()
    except sqlite3.Error:  # no table yet, or locked for a moment
        return {}
    out: dict = {}
    for number, state in sorted(rows):
        out.setdefault(str(state), []).append(number)
    return out


def _rows(path: Path) -> int:
    """Lines of a seed's live CSV (a checkpoint has written it); a large number if it is gone meanwhile."""
    try:
        return path.read_text().count("\n")
    except OSError:
        return 10**9


def _stop_mid_trial(results: Path, n_trials: int, signum: int, env: dict) -> int:
    """Start the search, send ``signum`` once a trial runs (after one completed) and its seeds have a checkpoint in the
    first half of their 2,000 generations (a trial runs them in a few seconds: 400 took about a second, which a loaded
    machine's poll could miss whole); return the number of the trial it stopped."""
    proc = subprocess.Popen(_search_command(results, n_trials), env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True)
    db = results / "k" / "optuna.db"
    stopped = None
    deadline = time.monotonic() + 240
    try:
        while time.monotonic() < deadline and proc.poll() is None:
            time.sleep(0.1)
            by_state = _states_read_only(db)
            running = by_state.get("RUNNING", [])
            if by_state.get("COMPLETE") and running and any(_rows(p) < 1000 for p in results.glob("k/snes-*/seed_0.partial.csv")):
                stopped = running[0]  # the running trial has started its seeds: stop it mid-trial
                proc.send_signal(signum)
                break
    finally:
        if proc.poll() is None and stopped is None:
            proc.kill()
        out = proc.communicate(timeout=120)[0]
    assert stopped is not None, "the search ended before it could be stopped mid-trial: " + out[-2000:]
    return stopped


@pytest.mark.slow
def test_a_search_killed_mid_trial_resumes_with_no_trial_lost_or_counted_twice(tmp_path):
    """SIGKILL while a trial runs (after at least one completed), then the same command: the killed trial is FAIL (why in
    its user attribute), re-run once with its parameters in the same run folder, and the study ends with exactly n_trials
    completed, the ones completed before the kill unchanged.

    Made to fail: with recover_stale_trials returning at once, the resumed search left the killed trial RUNNING (it
    counted as under way) and ended with 3 completed trials, not 4."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    n_trials = 4
    killed_number = _stop_mid_trial(tmp_path, n_trials, signal.SIGKILL, env)
    before = {t.number: (t.value, t.params) for t in study_of(tmp_path, "k").get_trials(states=(optuna.trial.TrialState.COMPLETE,))}
    killed = study_of(tmp_path, "k").trials[killed_number]
    assert killed.state == optuna.trial.TrialState.RUNNING  # as a kill -9 leaves it

    resumed = subprocess.run(_search_command(tmp_path, n_trials), env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:] + resumed.stdout[-3000:]
    assert f"trial {killed_number} was left running by a killed search" in resumed.stdout
    _assert_retried_once(tmp_path, n_trials, killed, before)
    assert "killed search" in study_of(tmp_path, "k").trials[killed_number].user_attrs["imix_stale"]
    assert "resuming" in resumed.stderr  # its seeds resumed from their checkpoints


@pytest.mark.slow
def test_a_search_stopped_by_ctrl_c_reruns_the_trial_it_stopped(tmp_path):
    """SIGINT (Ctrl-C) during a trial: the search ends with 130, the trial is FAIL and its parameters enqueued; the same
    command runs them (resuming the seeds' checkpoints) and ends with n_trials completed.

    Made to fail: with _tell_failed's retry ignored (no enqueue_trial), no completed trial was the stopped one's retry."""
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    n_trials = 3
    stopped_number = _stop_mid_trial(tmp_path, n_trials, signal.SIGINT, env)
    before = {t.number: (t.value, t.params) for t in study_of(tmp_path, "k").get_trials(states=(optuna.trial.TrialState.COMPLETE,))}
    stopped = study_of(tmp_path, "k").trials[stopped_number]
    assert stopped.state == optuna.trial.TrialState.FAIL and stopped.user_attrs["imix_failed"] == "the search stopped during the trial"
    resumed = subprocess.run(_search_command(tmp_path, n_trials), env=env, capture_output=True, text=True, timeout=600)
    assert resumed.returncode == 0, resumed.stderr[-3000:] + resumed.stdout[-3000:]
    _assert_retried_once(tmp_path, n_trials, stopped, before)
    assert "resuming" in resumed.stderr


def _assert_retried_once(results: Path, n_trials: int, lost, before: dict) -> None:
    """The study holds exactly ``n_trials`` completed trials, one FAIL (``lost``), none running; those completed before are
    unchanged; ``lost`` was re-run exactly once, with its parameters, in its run folder."""
    study = study_of(results, "k")
    complete = study.get_trials(states=(optuna.trial.TrialState.COMPLETE,))
    assert len(complete) == n_trials
    assert states(study).get("RUNNING") is None and states(study)["FAIL"] == [lost.number]
    for number, (value, params) in before.items():  # those completed before: the same trials, not re-run
        assert study.trials[number].value == value and study.trials[number].params == params
    retries = [t for t in complete if t.user_attrs.get("imix_retry_of") == lost.number]
    assert len(retries) == 1 and retries[0].params == lost.params  # re-run once, with its parameters
    assert f"sigma={lost.params['sigma']!r}" in Path(retries[0].user_attrs["run_dir"]).name  # in its run folder


def test_imix_plot_draws_the_study_and_prints_the_best_command(tmp_path, capsys):
    """Made to fail: with the study figure dropped from FIGURES, none of study_history/importances/slice was written."""
    assert main(["run", "-m", "hydra/sweeper=optuna", *TINY, *SPACE, "hydra.sweeper.n_trials=3", "hydra.sweeper.seed=2",
                 f"results_dir={tmp_path}", "experiment=p"]) == 0  # fmt: skip
    capsys.readouterr()
    assert main(["plot", f"results_dir={tmp_path}", "experiment=p", "only=study", "formats=png"]) == 0
    out = capsys.readouterr().out
    figures = tmp_path / "p" / "figures"
    for stem in ("study_history", "study_importances", "study_slice"):
        assert (figures / f"{stem}.png").stat().st_size > 10_000, stem
    assert (figures / "study_trials.csv").is_file() and "COMPLETE" in (figures / "study_trials.md").read_text()
    best = study_of(tmp_path, "p").best_trial
    line = next(line for line in out.splitlines() if "best trial" in line)
    assert f"trial {best.number}" in line and f"sigma={best.params['sigma']!r}" in line and "imix run algo=snes env=cartpole" in line


def test_pruning_stops_trials_early_marks_their_folders_and_keeps_completed_runs_exact(tmp_path, capsys):
    """hydra.sweeper.pruner=median: trials run in stages (1/4, 1/2, all of generations=40); pruned ones end PRUNED with
    their folder marked and left out of imix plot's runs; a completed trial's CSVs are those of the same run made at once.

    Made to fail: with mark_pruned's call removed, the pruned trials' folders had no PRUNED file (and imix plot read
    their partial CSVs as runs)."""
    from imix_cli.plotting.data import load_experiment
    from imix_cli.running.files.results import PRUNED_FILE

    common = ["algo=snes", "env=cartpole", "seeds=2", "generations=40", "eval_mean_every=5", "progress=false", "workers=1"]
    space = ["sigma=interval(0.01,0.5)", "lr=tag(log, interval(1e-3,1e-1))"]
    args = ["run", "-m", "hydra/sweeper=optuna", *common, *space, "hydra.sweeper.n_trials=10", "hydra.sweeper.pruner=median", "hydra.sweeper.seed=0"]
    assert main([*args, f"results_dir={tmp_path}", "experiment=p"]) == 0
    study = study_of(tmp_path, "p")
    by_state = states(study)
    assert by_state.get("PRUNED") and len(by_state["COMPLETE"]) + len(by_state["PRUNED"]) == 10, by_state
    for number in by_state["PRUNED"]:
        trial = study.trials[number]
        run_dir = Path(trial.user_attrs["run_dir"])
        assert (run_dir / PRUNED_FILE).is_file() and trial.user_attrs["pruned_at_generation"] in (10, 20)
        assert len(read_run_csv(run_dir / "seed_0.csv")) == trial.user_attrs["pruned_at_generation"]
    capsys.readouterr()
    assert main(["status", f"results_dir={tmp_path}", "experiment=p"]) == 0
    assert capsys.readouterr().out.count("pruned by an Optuna search") == len(by_state["PRUNED"])
    loaded = {g.path.name for g in load_experiment(tmp_path, "p", warn=lambda message: None).groups}
    assert loaded == {Path(study.trials[n].user_attrs["run_dir"]).name for n in by_state["COMPLETE"]}
    best = study.best_trial
    assert not (Path(best.user_attrs["run_dir"]) / PRUNED_FILE).exists()
    direct = [f"sigma={best.params['sigma']!r}", f"lr={best.params['lr']!r}"]
    assert main(["run", *common, *direct, f"results_dir={tmp_path / 'direct'}", "experiment=p"]) == 0
    for seed in range(2):
        staged = read_run_csv(Path(best.user_attrs["run_dir"]) / f"seed_{seed}.csv").drop(columns="wall_time")
        at_once = read_run_csv(next((tmp_path / "direct" / "p").glob(f"*/seed_{seed}.csv"))).drop(columns="wall_time")
        assert staged.equals(at_once)

"""Run an experiment from Python and get its results as a DataFrame: ``imix run`` without the shell.

Why: a notebook or a script that compares settings wants the rows, not a folder to parse. This
is ``imix run`` itself -- the same validation (:func:`imix_cli.running.config.compose.validate_overrides`), the
same runner (:func:`imix_cli.running.runner.run`: run folder, seeds over processes, checkpoints, resume,
summary) and the same CSVs -- with the CSV rows read back and returned::

    import imix_cli
    df = imix_cli.run(algo="snes", env="cartpole", eim=True, seeds=3, generations=50, experiment="try")
    df.groupby("generation")["mean_policy_score"].mean()

Keys are those of ``imix run`` (docs: the configuration reference), given as keywords (``eim=True``,
``policy={"hidden": []}``, ``**{"env.id": "Acrobot-v1"}``) or as ``key=value`` strings, with
Hydra's sweep syntax (``"popsize=10,25"``) for several runs. A keyword's value is a value, never
override syntax: ``experiment="a,b"`` names one folder ``a,b`` (a string from elsewhere cannot turn
into a sweep or an interpolation). Re-running the same call skips finished seeds and resumes the
others, as on the command line.

Without ``experiment=``, results go to ``<results_dir>/library/`` (:data:`DEFAULT_EXPERIMENT`), not to
``imix run``'s ``default/``: the command line's main job (1,000 generations) must not turn a later
``run(..., generations=50)`` into "a run is never shortened" error. A script may call ``run`` at its
top level, without ``if __name__ == "__main__":``: the worker processes never re-run the script
(:func:`imix_cli.core.processes.spawn_context`).
"""

from __future__ import annotations

__all__ = ["DEFAULT_EXPERIMENT", "Experiment", "run", "overrides_of"]

#: The experiment (sub-folder of ``results_dir``) of a library call that names none; ``imix run``'s is ``default``.
DEFAULT_EXPERIMENT = "library"


def overrides_of(*overrides: str, **keys) -> list[str]:
    """``key=value`` strings (as on ``imix run``'s command line) from strings and keyword arguments: how a call is shown.

    (What runs takes keyword values as values: :class:`Experiment`.) Booleans become ``true``/``false``, None
    ``null``, lists ``[a,b]``, and a mapping ``policy={"hidden": [16]}`` the dotted keys ``policy.hidden=[16]``."""
    out = [str(o) for o in overrides]

    def value(v) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if v is None:
            return "null"
        if isinstance(v, (list, tuple)):
            return "[" + ",".join(value(x) for x in v) + "]"
        return repr(v) if isinstance(v, float) else str(v)

    def add(key: str, v) -> None:
        if isinstance(v, dict):
            for k, sub in v.items():
                add(f"{key}.{k}", sub)
        else:
            out.append(f"{key}={value(v)}")

    for key, v in keys.items():
        add(key, v)
    return out


class Experiment:
    """One ``imix run`` command line (one run, or a sweep of several), validated when built.

    ``Experiment(algo="cem", eim=True, seeds=5).run()`` runs it and returns every seed's rows;
    :meth:`results` reads what exists without running anything. Bad keys or values raise
    :class:`~imix_cli.running.config.checks.ConfigError` (a ValueError) with ``imix run``'s one-line message.
    """

    def __init__(self, *overrides: str, progress: bool = False, **keys):
        from imix_cli.running.config.compose import validate_overrides

        self.overrides = [str(o) for o in overrides]
        # progress=False: a library call prints the summary, not a progress bar (progress=True restores it)
        self.values = {"progress": progress, **_dotted(keys)}
        named = any(o.split("=", 1)[0].lstrip("+~") == "experiment" for o in self.overrides) or "experiment" in self.values
        if not named:
            self.values["experiment"] = DEFAULT_EXPERIMENT
        self.specs = validate_overrides(self.overrides, values=self.values)

    def __repr__(self) -> str:
        return f"Experiment({', '.join([*map(repr, self.overrides), *(f'{k}={v!r}' for k, v in self.values.items())])})"

    @property
    def run_dirs(self) -> list:
        """The run folders, one per sweep point: ``<results_dir>/<experiment>/<run>/``."""
        return [spec.run_dir for spec in self.specs]

    def run(self, echo=print):
        """Run every point (finished seeds are skipped, others resumed); return :meth:`results`.

        ``echo`` receives each run's summary table (``print`` by default; ``None`` for silence).
        Raises :class:`~imix_cli.running.run_folder.RunError` if a run folder holds another config.
        """
        from imix_cli.running.runner import run as run_spec

        for spec in self.specs:
            run_spec(spec, echo=echo or (lambda text: None))
        return self.results()

    def results(self):
        """The rows of every finished seed of every point, as one DataFrame: the CSV columns
        (:data:`imix_cli.running.files.results.COLUMNS`) and ``run``, the run folder's name."""
        import pandas as pd

        from imix_cli.running.files.results import read_run_csv, seed_csv_path

        frames = []
        for spec in self.specs:
            for seed in range(spec.seeds):
                path = seed_csv_path(spec.run_dir, seed)
                if path.exists():
                    frames.append(read_run_csv(path).assign(run=spec.run_name))
        if not frames:
            from imix_cli.running.files.results import COLUMNS

            return pd.DataFrame(columns=[*COLUMNS, "run"])
        return pd.concat(frames, ignore_index=True)


def _dotted(keys: dict, prefix: str = "") -> dict:
    """``{"policy": {"hidden": [16]}}`` -> ``{"policy.hidden": [16]}``: a mapping's keys as dotted keys."""
    out = {}
    for key, v in keys.items():
        name = f"{prefix}{key}"
        out.update(_dotted(v, f"{name}.") if isinstance(v, dict) else {name: v})
    return out


def run(*overrides: str, echo=print, **keys):
    """Run an experiment as ``imix run`` would and return its rows as a pandas DataFrame.

    ``run(algo="snes", env="cartpole", eim=True, seeds=3, generations=50)`` is ``imix run algo=snes
    env=cartpole eim=true seeds=3 generations=50 progress=false``; see :class:`Experiment`.
    """
    return Experiment(*overrides, **keys).run(echo=echo)

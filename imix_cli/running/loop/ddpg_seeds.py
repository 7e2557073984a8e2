"""The DDPG baseline's trainer (the paper's section 4.3): its seed loop, one CSV row per episode.

stable-baselines3 runs through :mod:`imix_cli.core.ddpg.agent`, which knows SB3 and not files.
Seed k is SB3's seed=k; a worker runs its seeds one after another with one torch thread. Each
finished training episode is one CSV row (:func:`imix_cli.running.files.results.episode_row`: on
ContinuousCartPoleHard the sparse sum, which equals the dense return; sigma_mean = the OU
noise's sigma). An episode still running when total_steps is spent is not a row.

No checkpoint: SB3's state (replay buffer of up to 1e6 transitions, optimisers, noise) is not
saved mid-run, so a DDPG seed killed before its CSV is written restarts from scratch when the
command is re-run; finished seeds are skipped, like ES seeds.
"""

from __future__ import annotations

import time
from pathlib import Path

from imix_cli.messages import RunError
from imix_cli.running.files.results import episode_row, seed_csv_path, write_run_csv


def ddpg_row(spec, seed: int, episode, wall_time: float) -> dict:
    """The CSV row of one finished DDPG episode (an :class:`imix_cli.core.ddpg.agent.Episode`)."""
    return episode_row(
        algo=spec.algo, env=spec.env_name, mixing=spec.mixing, seed=seed, index=episode.index,
        env_steps=episode.env_steps, ret=episode.ret, sigma_mean=float(spec.ddpg["ou_sigma"]), wall_time=wall_time,
    )  # fmt: skip


def run_ddpg_seeds(spec, seeds: list[int], progress) -> dict:
    """Train DDPG for each of ``seeds`` in turn and write its CSV; ``progress(n)`` gets env steps.
    Returns seed -> :func:`imix_cli.running.files.results.seed_summary`."""
    from imix_cli.core.ddpg.agent import make_ddpg, train_ddpg

    summaries = {}
    for seed in seeds:
        rows = []
        started = time.perf_counter()
        model = make_ddpg(spec.env_id, spec.ddpg, seed=seed, max_steps=spec.env_max_steps)
        train_ddpg(
            model,
            spec.total_steps,
            on_episode=lambda ep, seed=seed, started=started, rows=rows: rows.append(ddpg_row(spec, seed, ep, time.perf_counter() - started)),
            on_steps=progress,
            torch_threads=1,
        )
        model.env.close()
        summaries[seed] = write_run_csv(seed_csv_path(spec.run_dir, seed), rows)
    return summaries


def needs_running(spec, seed: int, path: Path, frame) -> bool:
    """A finished DDPG seed is never continued; RunError if its CSV spent more steps than asked."""
    steps = int(frame["env_steps"].iloc[-1])
    if steps > spec.total_steps:
        raise RunError(f"{path}: has {steps} env steps, config asks for {spec.total_steps}; move it away or choose another experiment=")
    return False

"""The compiled generation loop (imix_cli.running.loop.compiled_loop) against the Python loop, its reference.

What must hold: the same rows, the same ES and archive state, the same random generators, the same
best member -- bit for bit -- after any number of chunks; whole runs through `imix run` (CSVs,
policies, checkpoints, a continued run) identical with IMIX_COMPILED_LOOP=0 and without; and where
the compiled loop does not apply, or meets a diverging update, the Python loop's rows exactly.
"""

import json
import os
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import pandas as pd
import pytest
from numba import njit

from imix_cli.core.algorithms.base import CompiledStep, EvolutionStrategy
from imix_cli.core.divergence import GuardedES
from imix_cli.core.evaluation.parallel import build_evaluator
from imix_cli.core.numerics.linalg_kernels import numpy_sum
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files.checkpoints import _encode, _read_npz
from imix_cli.running.loop import compiled_loop
from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state

CASES = [
    ["algo=snes", "env=cartpole", "eim=true"],  # the main job
    ["algo=openes", "env=cartpole", "eim=true", "popsize=20"],
    ["algo=snes", "env=cartpole", "eim=false", "popsize=12"],
    ["algo=snes", "env=cartpole", "im=true", "popsize=16"],
    ["algo=openes", "env=continuous_cartpole_hard", "im=true", "im_variant=sun2009", "im_alpha=0.1", "popsize=10"],
    ["algo=snes", "env=continuous_cartpole", "eim=true", "eim_generations=5", "weight_decay=0", "sigma=0.5", "lr=0.05"],
    ["algo=snes", "env=acrobot", "eim=true"],  # Acrobot: the float32 reset inside the loop's episodes
    ["algo=openes", "env=acrobot", "eim=false", "popsize=10"],
    ["algo=openes", "env=acrobot", "im=true", "popsize=16"],
    ["algo=cem", "env=cartpole", "eim=true"],  # CEM: elite weights (ties sharing theirs) are its mean weights
    ["algo=cem", "env=acrobot", "eim=false", "popsize=12"],
    ["algo=cem", "algo.style=cemrl", "env=cartpole", "im=true", "popsize=16"],
    # CMA-ES: a full Gaussian (its own chunk), TPA's two probes a generation, pycma's conditioning alleviated
    ["algo=cmaes", "env=cartpole", "eim=true"],
    ["algo=cmaes", "env=acrobot", "eim=false", "popsize=12"],
    ["algo=cmaes", "env=continuous_cartpole_hard", "eim=true", "eim_generations=5", "algo.step_size_control=csa", "popsize=10", "sigma=2"],
    # ARS: mirrored pairs (the anchors mixed and archived, the mirrors fresh), the top-b step, the reward's offset
    ["algo=ars", "env=cartpole", "eim=true"],
    ["algo=ars", "env=acrobot", "eim=false", "popsize=10"],
    ["algo=ars", "env=continuous_cartpole", "im=true", "im_variant=sun2009", "algo.top=4", "algo.alive_bonus_offset=-0.5", "popsize=16"],
]


def _seed_state(overrides, seed=3):
    (spec,) = validate_overrides([*overrides, "eval_mean_every=7", "eval_mean_episodes=3"])
    evaluator = build_evaluator(spec)
    settings = loop_settings(spec, evaluator)
    return settings, evaluator, new_seed_state(settings, seed)


def _snapshot(st) -> dict:
    """Everything a checkpoint would hold of the seed (its encoded tree and arrays), wall times aside."""
    arrays = {}
    tree = _encode(st, "", arrays)
    return {"tree": repr(tree), "arrays": {k: v.copy() for k, v in arrays.items()}}


def _same(a: dict, b: dict) -> None:
    assert a["tree"] == b["tree"]
    assert sorted(a["arrays"]) == sorted(b["arrays"])
    for name in a["arrays"]:
        np.testing.assert_array_equal(a["arrays"][name], b["arrays"][name], err_msg=name, strict=True)


def _agree_chunk_by_chunk(python, compiled, settings, evaluator, chunks) -> None:
    """Seed ``python`` through the Python loop and ``compiled`` through compiled chunks of these lengths (the archive
    carried from one to the next): the same state after every chunk."""
    assert compiled_loop.applies(settings, evaluator, compiled)
    for chunk in chunks:
        for _ in range(chunk):
            advance_lockstep([python], settings, evaluator)
        assert compiled_loop.advance(compiled, settings, evaluator, chunk)
        for row in python.rows + compiled.rows:
            row["wall_time"] = 0.0
        _same(_snapshot(python), _snapshot(compiled))


@pytest.mark.parametrize("overrides", CASES, ids=lambda o: " ".join(o))
def test_compiled_chunks_give_the_python_loops_state_bit_for_bit(overrides):
    settings, evaluator, python = _seed_state(overrides)
    _, _, compiled = _seed_state(overrides)
    _agree_chunk_by_chunk(python, compiled, settings, evaluator, (1, 4, 25, 30))
    reused = sum(row["reused"] for row in python.rows)
    assert python.generation == 60 and (reused == 0 if "eim=false" in overrides else reused > 100)
    assert any(np.isfinite(row["mean_policy_score"]) for row in python.rows)


class _ToyState(NamedTuple):
    """The toy ES's state record (docs/development.md, "An ES"): mean and std first, then its own."""

    mean: np.ndarray
    std: np.ndarray
    steps: np.ndarray  # int64 (1,)


class _ToyConstants(NamedTuple):
    lr: float


@njit
def _toy_update(samples, utilities, state, constants):
    """mu += lr * mean_i u_i (x_i - mu); sigma *= 0.99 every generation (a made-up ES: not OpenES's or SNES's update)."""
    n, d = samples.shape
    for j in range(d):
        g = 0.0
        for i in range(n):
            g += utilities[i] * (samples[i, j] - state.mean[j])
        state.mean[j] += constants.lr * g / n
        state.std[j] *= 0.99
    state.steps[0] += 1


class _ToyES(EvolutionStrategy):
    """An ES of the documented recipe with a compiled step (docs/development.md, "An ES")."""

    name = "toy"

    def _setup(self):
        self.set_state(_ToyState(self.initial_mean.copy(), np.full(self.dim, self.sigma), np.zeros(1, dtype=np.int64)))

    @property
    def distribution(self):
        return self._dist

    def _update(self, samples, utilities):
        self._update_compiled(samples, utilities)

    def compiled_step(self):
        return CompiledStep(_toy_update, _ToyConstants(self.lr))

    @property
    def steps(self):
        return int(self.state.steps[0])


def test_any_es_with_a_compiled_step_runs_in_the_compiled_loop():
    states = []
    for _ in range(2):
        settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true", "popsize=12"])
        st.es = GuardedES(_ToyES(settings.dim, popsize=12, lr=0.5))
        states.append(st)
    python, compiled = states
    _agree_chunk_by_chunk(python, compiled, settings, evaluator, (3, 17))
    assert compiled.es.steps == 20 and sum(row["reused"] for row in compiled.rows) > 20
    assert compiled.rows[-1]["sigma_mean"] == pytest.approx(0.25 * 0.99**19)


_USER_ES_MODULE = """
from typing import NamedTuple

import numpy as np
from numba import njit

from imix_cli.core.algorithms.base import CompiledStep, EvolutionStrategy


class UserState(NamedTuple):
    mean: np.ndarray
    std: np.ndarray


class UserConstants(NamedTuple):
    lr: float


@njit
def user_update(samples, utilities, state, constants):
    for j in range(samples.shape[1]):
        state.mean[j] += constants.lr * (samples[0, j] - state.mean[j]) * utilities[0]


class UserES(EvolutionStrategy):
    name = "user"

    def _setup(self):
        self.set_state(UserState(self.initial_mean.copy(), np.full(self.dim, self.sigma)))

    @property
    def distribution(self):
        return self._dist

    def _update(self, samples, utilities):
        self._update_compiled(samples, utilities)

    def compiled_step(self):
        return CompiledStep(user_update, UserConstants(self.lr))
"""

_USER_SCRIPT = """
import sys

sys.path.insert(0, sys.argv[1])  # the user's own folder: no other process can import user_es_module
from user_es_module import UserES

from imix_cli.core.evaluation.parallel import build_evaluator
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.loop import compiled_loop
from imix_cli.running.loop.lockstep import loop_settings, new_seed_state

(spec,) = validate_overrides(["algo=snes", "env=cartpole", "eim=true", "popsize=6"])
evaluator = build_evaluator(spec)
settings = loop_settings(spec, evaluator)
st = new_seed_state(settings, 0)
st.es = UserES(settings.dim, popsize=6)
assert compiled_loop.advance(st, settings, evaluator, 2)
print("the user's ES ran compiled")
"""


def test_an_es_of_a_users_module_leaves_the_cache_readable_for_every_other_run(tmp_path):
    """numba's cache index of a compiled entry holds its arguments' types, the ES's state record class among them, and
    numba imports that class's module when it reads the index. Once every ES shared one index: after a user's script ran
    an ES of a module of theirs compiled, every ``imix run`` elsewhere died importing that module. Each entry now has an
    index of its own (:func:`imix_cli.core.mixing.compiled_generation.entry`)."""
    lib = tmp_path / "lib"
    lib.mkdir()
    (lib / "user_es_module.py").write_text(_USER_ES_MODULE)
    (lib / "user_script.py").write_text(_USER_SCRIPT)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(Path(__file__).resolve().parents[1]), os.environ.get("PYTHONPATH")]))}
    first = subprocess.run([sys.executable, str(lib / "user_script.py"), str(lib)], capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert first.returncode == 0 and "the user's ES ran compiled" in first.stdout, first.stderr[-2000:]
    run = [sys.executable, "-c", "import sys; from imix_cli.commands.cli import main; sys.exit(main())", "run", "algo=snes", "env=cartpole",
           "eim=true", "seeds=1", "generations=3", "progress=false", "workers=1", f"results_dir={tmp_path / 'results'}"]  # fmt: skip
    second = subprocess.run(run, capture_output=True, text=True, env=env, cwd=tmp_path, timeout=900)
    assert second.returncode == 0, second.stderr[-2000:]
    assert any((tmp_path / "results").rglob("seed_0.csv"))


def test_an_es_with_mean_weights_of_its_own_in_python_only_is_left_to_the_python_loop():
    from imix_cli.core.algorithms.snes import SNES

    class _Elitist(SNES):  # the archive's mean weights would be the utilities in the compiled loop, not these
        def _mean_weights(self, utilities):
            return np.maximum(utilities, 0.0)

    settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true", "popsize=12"])
    assert compiled_loop.applies(settings, evaluator, st)
    st.es = GuardedES(_Elitist(settings.dim, popsize=12))
    assert not compiled_loop.applies(settings, evaluator, st)


def test_a_chunk_that_diverges_changes_nothing_and_is_left_to_the_python_loop():
    # lr=100: SNES's log sigma overflows within a few generations (imix_cli.core.divergence)
    settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true", "lr=100", "weight_decay=0"])
    before = _snapshot(st)
    assert not compiled_loop.advance(st, settings, evaluator, 200)
    _same(before, _snapshot(st))


def test_a_cmaes_chunk_that_cannot_draw_changes_nothing_and_is_left_to_the_python_loop():
    """A full Gaussian's chunk meets a covariance that is not positive definite (sigma^2 overflows): it hands the seed
    back unchanged, and the Python path records the divergence."""
    settings, evaluator, st = _seed_state(["algo=cmaes", "env=cartpole", "eim=true"])
    st.es.es.state.step_size[0] = 1e160
    before = _snapshot(st)
    assert not compiled_loop.advance(st, settings, evaluator, 20)
    _same(before, _snapshot(st))
    advance_lockstep([st], settings, evaluator)
    assert st.es.diverged and st.generation == 1


@pytest.mark.parametrize(
    "overrides",
    [CASES[0], ["algo=cem", "env=acrobot", "eim=true", "popsize=12"], ["algo=cmaes", "env=cartpole", "eim=true", "popsize=12"], CASES[15]],
    ids=lambda o: " ".join(o),
)
def test_seeds_advanced_together_are_the_seeds_advanced_alone_bit_for_bit(overrides):
    """One compiled call advances many seeds, their fresh members' episodes in one batch (compiled_generation
    SEEDS_PER_CALL): every seed's state must be the one it reaches alone, seeds with archives of different ages and a
    padded call included. Made to fail by giving each seed the episode seeds of the batch's first seed."""
    settings, evaluator, _ = _seed_state(overrides)
    alone = [new_seed_state(settings, seed) for seed in range(5)]
    together = [new_seed_state(settings, seed) for seed in range(5)]
    for st in (alone[0], together[0]):  # seed 0 starts with a full archive, the others with none
        assert compiled_loop.advance(st, settings, evaluator, 4)
    for st in alone[1:]:
        assert compiled_loop.advance(st, settings, evaluator, 4)
    assert compiled_loop.advance_seeds(together[1:], settings, evaluator, 4)
    for chunk in (9, 5):
        for st in alone:
            assert compiled_loop.advance(st, settings, evaluator, chunk)
        assert compiled_loop.advance_seeds(together, settings, evaluator, chunk)
    for a, b in zip(alone, together):
        for row in a.rows + b.rows:
            row["wall_time"] = 0.0
        _same(_snapshot(a), _snapshot(b))
    assert len({st.rows[-1]["mean_score"] for st in together}) > 1  # the seeds differ


@pytest.mark.parametrize("overrides", [CASES[0], CASES[12]], ids=lambda o: " ".join(o))
def test_every_argument_of_a_call_but_the_generators_is_typed_from_its_fingerprint(overrides, monkeypatch):
    """numba types a compiled call's arguments before every call: in C, from a fingerprint, an argument made of tuples,
    records and arrays; field by field in Python one that holds anything else -- a numpy Generator, say -- which cost
    the main job's calls 9 ms each (16 seeds' tuples), ~0.35 s of a worker's 3 s. So the seeds' generators are an
    argument of their own (compiled_generation._seed_list) and every other argument must have a fingerprint. Made to
    fail by putting the generators back in the seeds' tuples."""
    from numba._dispatcher import compute_fingerprint  # what numba's dispatcher runs on each argument, in C

    settings, evaluator, _ = _seed_state(overrides)
    states = [new_seed_state(settings, seed) for seed in range(3)]
    calls, entry_for = [], compiled_loop.entry_for

    def recording_entry_for(*args):
        run = entry_for(*args)

        def recorded(*call):
            calls.append(call)
            return run(*call)

        return recorded

    monkeypatch.setattr(compiled_loop, "entry_for", recording_entry_for)
    assert compiled_loop.advance_seeds(states, settings, evaluator, 2)
    (call,) = calls
    holds_generators = [isinstance(a, tuple) and isinstance(a[0], tuple) and isinstance(a[0][0], np.random.Generator) for a in call]
    assert sum(holds_generators) == 1
    for argument, generators in zip(call, holds_generators):
        if not generators:
            compute_fingerprint(argument)  # NotImplementedError: numba would type it in Python


def test_a_call_whose_one_seed_diverges_changes_no_seed_and_is_left_to_the_python_loop():
    """Seeds advanced together are handed back together: the states and generators of all of them as they were."""
    settings, evaluator, _ = _seed_state(["algo=snes", "env=cartpole", "eim=true", "lr=100", "weight_decay=0"])
    states = [new_seed_state(settings, seed) for seed in range(3)]
    before = [_snapshot(st) for st in states]
    rngs = [[r.bit_generator.state for r in (st.sample_rng, st.episode_rng, st.mean_eval_rng)] for st in states]
    assert not compiled_loop.advance_seeds(states, settings, evaluator, 200)
    for st, snap, rng in zip(states, before, rngs):
        _same(snap, _snapshot(st))
        assert rng == [r.bit_generator.state for r in (st.sample_rng, st.episode_rng, st.mean_eval_rng)]


def test_the_compiled_loop_applies_only_where_it_reproduces_the_python_loop():
    for overrides in (
        ["algo=cmaes", "env=cartpole", "im=true"],  # between full Gaussians only "exact" has a compiled step
        ["algo=snes", "env=cartpole", "eim=true", "eim_variant=conditional"],
        ["algo=snes", "env=cartpole", "eim=true", "reeval_count=2"],
        ["algo=snes", "env=cartpole", "eim=true", "weight_decay_form=paper"],
        ["algo=snes", "env=cartpole", "eim=true", "reeval_age=3"],
        ["algo=snes", "env=cartpole", "eim=true", "evaluator=pool"],
        ["algo=snes", "env=cartpole", "eim=true", "policy.bias=false"],  # ES points are not the policy's parameters
        ["algo=ars", "env=cartpole", "eim=true", "policy.bias=false"],
        ["algo=ars", "env=cartpole", "eim=true", "reeval_prob=0.5"],
        ["algo=ars", "env=cartpole", "eim=true", "eim_variant=conditional"],
    ):
        settings, evaluator, st = _seed_state(overrides)
        assert not compiled_loop.applies(settings, evaluator, st), overrides
    taken = (
        ["algo=snes", "env=acrobot", "eim=true"],
        ["algo=openes", "env=continuous_cartpole_hard", "im=true"],
        ["algo=cem", "env=acrobot", "eim=true"],
        ["algo=cmaes", "env=cartpole", "eim=true"],
        ["algo=cmaes", "env=acrobot", "eim=false"],
        ["algo=ars", "env=acrobot", "im=true"],
    )
    for overrides in taken:
        settings, evaluator, st = _seed_state(overrides)
        assert compiled_loop.applies_to_run(settings, evaluator) and compiled_loop.applies(settings, evaluator, st), overrides
    settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true"])
    os.environ[compiled_loop.ENV_VARIABLE] = "0"
    try:
        assert not compiled_loop.applies(settings, evaluator, st)
    finally:
        del os.environ[compiled_loop.ENV_VARIABLE]


def test_numpy_sum_is_numpys_pairwise_sum():
    rng = np.random.default_rng(7)
    for n in [*range(0, 300), 1000, 1023, 1024, 4097, 70001]:
        for _ in range(5):
            a = rng.standard_normal(n) * 10.0 ** rng.uniform(-4, 4, n)
            assert numpy_sum(a) == np.sum(a), n
            if n:
                assert numpy_sum(a) / n == np.mean(a), n


def _run(args, results_dir, **env):
    environ = {**os.environ, "PYTHONHASHSEED": "0", **env}
    done = subprocess.run(
        [sys.executable, "-m", "imix_cli.commands.cli", "run", *args, f"results_dir={results_dir}", "progress=false"],
        env=environ, capture_output=True, text=True, timeout=600,
    )  # fmt: skip
    assert done.returncode == 0, done.stderr


def _without_times(header: dict, arrays: dict) -> dict:
    """A checkpoint's content less what measures wall time: the seed's elapsed seconds, its rows'
    wall_time column, and the checksum and header that cover them."""
    state = header["state"]["state"]
    state.pop("elapsed")
    rows = state["rows"]["table"]
    wall = rows["columns"][rows["keys"].index("wall_time")]["float"]
    arrays = dict(arrays)
    arrays[rows["float"]] = np.delete(arrays[rows["float"]], wall, axis=0)
    return {"header": json.dumps(state, sort_keys=True), **arrays}


def _files(root: Path) -> dict:
    out = {}
    for path in sorted(root.rglob("*")):
        if path.suffix == ".csv":
            out[path.relative_to(root)] = pd.read_csv(path).drop(columns=["wall_time"])
        elif path.suffix == ".npz" and path.parent.name == ".checkpoints":
            header, arrays = _read_npz(path, 1 << 30)
            out[path.relative_to(root)] = _without_times(header, arrays)
        elif path.suffix == ".npz":
            with np.load(path) as z:
                out[path.relative_to(root)] = {k: z[k] for k in z.files}
    return out


RUNS = [
    ["algo=snes", "env=cartpole", "eim=true"],
    ["algo=snes", "env=acrobot", "eim=true"],
    ["algo=openes", "env=acrobot", "eim=false", "popsize=12"],
    ["algo=cem", "env=acrobot", "eim=true"],
    ["algo=cmaes", "env=cartpole", "eim=true", "popsize=20"],
    ["algo=ars", "env=cartpole", "eim=true", "algo.alive_bonus_offset=-0.25"],
]


@pytest.mark.slow
@pytest.mark.parametrize("run", RUNS, ids=lambda o: " ".join(o))
def test_runs_are_identical_with_the_python_loop_continued_runs_included(tmp_path, run):
    args = [*run, "seeds=3", "workers=2", "checkpoint_every=20", "checkpoint_seconds=0", "experiment=x"]
    for name, env in (("python", {compiled_loop.ENV_VARIABLE: "0"}), ("compiled", {})):
        _run([*args, "generations=45"], tmp_path / name, **env)
        _run([*args, "generations=90"], tmp_path / name, **env)  # continued from the final states
    python, compiled = _files(tmp_path / "python"), _files(tmp_path / "compiled")
    assert sorted(python) == sorted(compiled) and any(str(p).endswith("seed_2.csv") for p in python)
    for path, value in python.items():
        if isinstance(value, pd.DataFrame):
            assert len(value) == 90
            pd.testing.assert_frame_equal(value, compiled[path], check_exact=True)
        else:
            assert sorted(value) == sorted(compiled[path]), path
            for k in value:
                if k == "header":
                    assert value[k] == compiled[path][k], path
                    continue
                np.testing.assert_array_equal(value[k], compiled[path][k], err_msg=f"{path}:{k}", strict=True)


def test_the_live_csv_text_is_pandas_text_in_pieces():
    from imix_cli.running.files.results import csv_text, rows_csv_text, rows_to_frame

    settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true", "popsize=10"])
    compiled_loop.advance(st, settings, evaluator, 40)
    rows = [dict(r) for r in st.rows]
    for r, value in zip(rows, [np.inf, -np.inf, -0.0, 1e-300, 123456789.123456, float("nan"), 2.0**60, 0.1]):
        r["wall_time"] = value  # awkward floats
    rows[3]["algo"] = "a,b"  # a value pandas quotes
    rows[4]["env"] = 'say "x"'
    rows[6]["env"] = "nan"  # a string that reads like a NaN float: pandas writes it as it is
    rows[8]["mean_score"] = rows[9]["best_score"] = float("nan")  # NaN floats beside others, and inf: written empty, inf
    rows[9]["mean_policy_score"] = float("inf")
    whole = csv_text(rows_to_frame(rows))
    assert rows_csv_text(rows) == whole
    assert rows_csv_text(rows[:7]) + rows_csv_text(rows[7:20], header=False) + rows_csv_text(rows[20:], header=False) == whole
    plain = rows[5:]
    assert rows_csv_text(plain) == csv_text(rows_to_frame(plain))


def test_a_seed_csv_of_plain_rows_is_written_and_summed_up_as_pandas_does(tmp_path):
    from imix_cli.running.files.results import csv_text, rows_to_frame, seed_summary, write_run_csv

    settings, evaluator, st = _seed_state(["algo=snes", "env=cartpole", "eim=true", "popsize=10", "eval_mean_every=7"])
    compiled_loop.advance(st, settings, evaluator, 40)
    diverged = [dict(r) for r in st.rows]
    diverged[-1]["diverged"] = 1
    never_measured = [{k: v for k, v in r.items() if not k.startswith("mean_policy")} for r in st.rows]
    for rows in (st.rows, diverged, never_measured):
        summary = write_run_csv(tmp_path / "seed_0.csv", rows)
        frame = rows_to_frame(rows)
        assert (tmp_path / "seed_0.csv").read_text() == csv_text(frame)
        expected = seed_summary(frame)
        assert summary.keys() == expected.keys()
        for key, value in expected.items():
            assert type(summary[key]) is type(value) and (summary[key] == value or (value != value and summary[key] != summary[key])), key


def test_a_worker_writes_a_seed_csv_without_pandas(tmp_path):
    """Importing pandas costs a worker process ~0.25 s of its start: the modules a worker runs and the
    CSV of plain rows must not need it."""
    code = (
        "import sys\n"
        "import imix_cli.running.runner, imix_cli.running.loop.es_seeds, imix_cli.running.loop.compiled_loop\n"
        "from imix_cli.running.files.results import write_run_csv\n"
        "row = dict(algo='snes', env='cartpole', mixing='eim', seed=0, generation=0, evaluations=5, env_steps=50, mean_score=1.5,\n"
        "           best_score=2.0, reused=0, reused_im=0, reused_eim=0, reevaluated=0, popsize=5, sigma_mean=0.1, nonfinite=0, wall_time=0.1)\n"
        f"write_run_csv({str(tmp_path / 'seed_0.csv')!r}, [row])\n"
        "assert 'pandas' not in sys.modules, 'pandas imported'\n"
    )
    done = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert done.returncode == 0, done.stderr[-2000:]

"""`imix bench` on tiny sizes: every section runs and prints its rows and columns; bad
arguments give one line and exit status 2. (No timings are asserted: speed is measured by
`imix bench` itself, on a machine of the user's choosing.)"""

import sys
import tempfile

import numpy as np
import pytest

from imix_cli.bench import main
from imix_cli.bench.rollouts import bench_policies
from imix_cli.commands.cli import main as cli_main
from imix_cli.core.evaluation import make_evaluator

TINY = ["sizes=3,12", "repeats=1", "min_seconds=0", "naive_members=2", "dims=20", "seeds=2", "generations=2"]


def _tables(text: str) -> dict[str, list[list[str]]]:
    """Markdown tables of the output, by the heading line above each: rows of cells (header first)."""
    tables, heading = {}, None
    for line in text.splitlines():
        if line.startswith("## "):
            heading = line[3:]
            tables[heading] = []
        elif line.startswith("|") and heading is not None and not line.startswith("|---"):
            tables[heading].append([c.strip() for c in line.strip("|").split("|")])
    return tables


def _si(text: str) -> float:
    """A rate as imix bench prints it (``1.25M``, ``830k``, ``412``)."""
    scale = {"G": 1e9, "M": 1e6, "k": 1e3}.get(text[-1], 1.0)
    return float(text[:-1] if scale != 1.0 else text) * scale


def _table(tables, prefix):
    (rows,) = [rows for heading, rows in tables.items() if heading.startswith(prefix)]
    return rows[0], rows[1:]


def test_rollouts_and_mixing_rows_and_columns(capsys):
    assert main(["rollouts", "mixing", *TINY]) == 0
    tables = _tables(capsys.readouterr().out)
    assert len(tables) == 2
    header, rows = _table(tables, "Rollouts")
    assert header == ["env", "batch", "mean episode", "batched (steps/s)", "SyncVectorEnv (steps/s)",
                      "naive loop (steps/s)", "× SyncVectorEnv", "× naive"]  # fmt: skip
    assert [(r[0], r[1]) for r in rows] == [("cartpole", "3"), ("cartpole", "12"), ("acrobot", "3"), ("acrobot", "12")]
    for env, batch, mean_episode, batched, sync, naive, x_sync, x_naive in rows:
        # the episodes the bench timed are those of its fixed policies and seeds 0..B-1: their mean length, recomputed here
        # (B = 12 on CartPole: lengths 10 to 200, so a mean is not a maximum or a cap)
        _, steps = make_evaluator(env).evaluate(bench_policies(env, int(batch)), np.arange(int(batch)))
        assert mean_episode == f"{np.mean(steps):.0f}"
        # each ratio is the batched evaluator's rate over its baseline's, as printed (3 significant digits each)
        assert float(x_sync) == pytest.approx(_si(batched) / _si(sync), rel=0.06, abs=0.06)
        assert float(x_naive) == pytest.approx(_si(batched) / _si(naive), rel=0.06, abs=0.6)
    header, rows = _table(tables, "One importance-mixing step")
    assert header == ["d", "plain sample (ms)", "variant", "mix (ms)", "mix / sample", "reuse"]
    assert [(r[0], r[2]) for r in rows] == [("20", "paper"), ("20", "exact"), ("20", "sun2009")]
    for _, sample_ms, _, mix_ms, ratio, reuse in rows:
        # the times are printed to 0.001 ms (tens of microseconds at d = 20): the ratio of the printed times is off by as
        # much as their rounding allows, and the printed ratio by 0.005
        m, s = float(mix_ms), float(sample_ms)
        rounding = (m / s) * (0.0005 / s + 0.0005 / m) + 0.005
        assert float(ratio) == pytest.approx(m / s, abs=rounding + 0.01 * m / s)
        # the bench's archive moved by 0.05 sigma in all: nearly the same law, so most members are reused (0.86-0.94 seen)
        assert 0.7 <= float(reuse) <= 1.0


def test_loop_compares_the_compiled_and_python_loops_on_the_same_rows(capsys):
    assert main(["loop", "seeds=2", "generations=30"]) == 0
    header, rows = _table(_tables(capsys.readouterr().out), "The compiled generation loop")
    assert header[0] == "run" and header[-1] == "same rows"
    assert [r[0] for r in rows] == ["snes cartpole true", "openes cartpole true", "snes cartpole false", "ars cartpole true"]
    assert all(r[-1] == "yes" and float(r[3]) > 0 and float(r[4]) > 0 for r in rows)


@pytest.mark.slow
def test_memory_breakdown_and_grid(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))  # where the runs' temporary folders go
    args = ["memory", "breakdown", "grid", *TINY, "algos=snes,cem", "envs=cartpole", "workers=1"]
    assert cli_main(["bench", *args]) == 0
    tables = _tables(capsys.readouterr().out)
    header, rows = _table(tables, "A 25-seed run")
    assert header == ["command", "wall (s)", "CPU (s): main / all workers", "main process peak RSS (MB)",
                      "largest worker peak RSS (MB)", "sum of peaks (MB)"]  # fmt: skip
    assert len(rows) == 1 and "seeds=2" in rows[0][0] and float(rows[0][3]) > 10
    header, rows = _table(tables, "Where a run's time goes")
    assert header[:5] == ["run", "seeds", "generations", "d", "time (s)"] and "mixing + update" in header
    assert [r[0].split("-")[0] for r in rows] == ["snes", "cem"] and all(r[3] == "130" for r in rows)
    header, rows = _table(tables, "The paper's main grid")
    assert header == ["run", "seeds", "generations", "wall (s)", "CPU (s)", "env steps", "evaluations", "final mean score"]
    names = [r[0] for r in rows]
    assert names[:4] == [
        "snes-cartpole-none", "cem-cartpole-none", "snes-cartpole-eim", "cem-cartpole-eim",  # estool: the default now
    ]  # fmt: skip
    assert names[4:] == ["**total, mixing=none**", "**total, mixing=eim**", "**grid total**"]
    assert all(int(r[5].replace(",", "")) > 0 for r in rows[:4])
    # temporary results are cleaned up (pymp-*: multiprocessing's own folder, its fork server's socket, removed at exit)
    assert not [p for p in tmp_path.iterdir() if not p.name.startswith("pymp-")]


@pytest.mark.parametrize(
    ("args", "named"),
    [(["nonsense"], "'nonsense'"), (["sizes=0"], "sizes"), (["sizes=x"], "sizes"), (["sizes=3,"], "sizes"), (["repeats=-1"], "repeats"),
     (["envs=pong"], "'pong'"), (["rollouts", "dims="], "dims"), (["algos=ddpg"], "'ddpg'"), (["seedz=3"], "'seedz'"),
     (["quick=maybe"], "quick"), (["min_seconds=-1"], "min_seconds"), (["--seeds", "5"], "'--seeds'"), (["--quick"], "'--quick'"),
     (["rollouts", "--dims", "20"], "'--dims'"), (["--grid"], "'--grid'"), (["-x"], "'-x'")],
)  # fmt: skip
def test_bad_arguments_one_line_naming_them_exit_2(capsys, args, named):
    """key=value is the only style (as imix plot, eval, render, status): ``--seeds 5`` is refused, naming ``--seeds``."""
    assert cli_main(["bench", *args]) == 2
    captured = capsys.readouterr()
    assert captured.out == ""
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("imix bench: ") and named in lines[0], lines


def test_key_value_arguments():
    from imix_cli.bench.cli import parse_args

    args = parse_args(["peers", "loop", "seeds=3", "generations=40", "envs=cartpole,acrobot", "quick=true", "min_seconds=0.5", "peers"])
    assert args.sections == ["peers", "loop"]  # unique, in order
    assert (args.seeds, args.generations, args.envs, args.quick, args.min_seconds) == (3, 40, ["cartpole", "acrobot"], True, 0.5)
    default = parse_args([])
    assert default.sections == ["rollouts", "mixing", "memory"] and default.sizes == [2, 50, 1250] and default.seeds is None
    assert parse_args(["all"]).sections == ["rollouts", "mixing", "memory", "breakdown", "loop", "grid", "peers", "mujoco"]


def test_help(capsys):
    assert cli_main(["bench", "--help"]) == 0
    out = capsys.readouterr().out
    assert out.startswith("usage: imix bench") and all(s in out for s in ("rollouts", "mixing", "memory", "grid"))
    assert "seeds=" in out and "--seeds" not in out


def test_peers_without_the_extra_say_how_to_install_and_exit_0(capsys, monkeypatch):
    monkeypatch.setitem(sys.modules, "evosax", None)  # import evosax -> ImportError
    assert cli_main(["bench", "peers", "quick=true"]) == 0
    out = capsys.readouterr().out
    assert 'pip install ".[peers]" from the imix clone' in out and "evosax" in out and "|" not in out  # no table


@pytest.mark.slow
@pytest.mark.peers
def test_peers_rows_and_columns(capsys, tmp_path, monkeypatch):
    monkeypatch.setattr(tempfile, "tempdir", str(tmp_path))
    assert cli_main(["bench", "peers", "seeds=1", "generations=2", "envs=cartpole"]) == 0
    tables = _tables(capsys.readouterr().out)
    header, rows = _table(tables, "Peers")
    assert header == ["run", "env", "seeds", "generations", "wall (s)", "of which compile (s)", "env steps",
                      "final mean score"]  # fmt: skip
    first = "imix run algo=snes eim=true, first run (empty numba cache)"
    whole = "imix run algo=snes eim=true, the whole process (cache warm), median of "  # then its runs' wall times
    assert [r[0] for r in rows[:4]] + [rows[4][0][: len(whole)]] + [r[0] for r in rows[5:]] == [
        "evosax SNES + gymnax", "evosax Open_ES + gymnax", first, "imix run algo=snes eim=true", whole,
        "imix run algo=snes eim=true checkpoint_seconds=0", "imix run algo=snes eim=false"]  # fmt: skip
    assert len(rows[4][0][len(whole) :].split(", ")) == 3
    steps = [int(r[6].replace(",", "")) for r in rows]
    assert all(r[1:4] == ["cartpole", "1", "2"] for r in rows)
    # no mixing in the first generation: 50 episodes each; the peers' episodes count their own steps only
    assert all(50 <= s < 50 * 200 for s in steps) and rows[0][5] and not rows[3][5]  # early episodes are short
    # the first run (a new process, numba compiling) computes what the warm run computes; its compile is filled in
    assert rows[2][5] and rows[2][6:] == rows[3][6:]
    assert rows[4][6:] == rows[3][6:]  # the whole process: the same run, in a new process
    assert rows[5][6:] == rows[3][6:]  # checkpoints every 50 generations: the same run, more written
    header, rows = _table(tables, "Ratios")
    assert header == ["env", "comparison", "× faster (wall)", "× fewer env steps"]
    others = ["evosax SNES + gymnax", "evosax Open_ES + gymnax", "imix run algo=snes eim=false"]
    runs = (", first run", "", ", the whole process", ", checkpoints every 50 generations")
    assert [r[1] for r in rows] == [f"imix SNES + EIM{run} vs {other}" for run in runs for other in others]
    assert all(float(r[2]) > 0 and float(r[3]) > 0 for r in rows)
    assert not [p for p in tmp_path.iterdir() if not p.name.startswith("pymp-")]  # pymp-*: multiprocessing's own

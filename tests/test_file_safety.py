"""Files in a results folder, and policy files, are data: they never import a module, never make imix
write outside the run folder, never use unbounded memory, and are validated field by field.

Each test names the way a file could lie (a module in an env id, a symlink, a zip bomb, a checkpoint
forged with a recomputed checksum, a policy header out of range, a copied or reordered CSV) and
checks that imix refuses it in one line -- never a traceback, never a changed number.
"""

from __future__ import annotations

import io
import json
import os
import struct
import subprocess
import sys
import textwrap
import zipfile
import zlib
from pathlib import Path

import numpy as np
import pytest

from imix_cli.commands.cli import main
from imix_cli.running.files.policy_files import policy_path, read_policy, write_policy

RUN = "cem-cartpole-none-popsize=6"
IMIX = str(Path(sys.executable).parent / "imix")
TINY = ["algo=cem", "env=cartpole", "seeds=1", "generations=2", "popsize=6", "progress=false", "workers=1"]

#: A gymnasium env of the user's own, in a module of its own; it notes every import of the module in
#: the file named by IMIX_TEST_IMPORT_LOG, so a test sees whether imix imported it.
USER_ENV_MODULE = '''
import os
import numpy as np
import gymnasium as gym
from gymnasium import spaces

if os.environ.get("IMIX_TEST_IMPORT_LOG"):
    with open(os.environ["IMIX_TEST_IMPORT_LOG"], "a") as log:
        log.write(__name__ + "\\n")


class Reach1D(gym.Env):
    """Walk left or right to reach x = 1: a tiny discrete-action env."""

    metadata = {"render_modes": ["rgb_array"], "render_fps": 10}

    def __init__(self, render_mode=None):
        self.render_mode = render_mode
        self.observation_space = spaces.Box(-10.0, 10.0, (1,), dtype=np.float32)
        self.action_space = spaces.Discrete(2)

    def reset(self, seed=None, options=None):
        super().reset(seed=seed)
        self.x = float(self.np_random.uniform(-1, 1))
        return np.array([self.x], dtype=np.float32), {}

    def step(self, action):
        self.x += 0.1 if action == 1 else -0.1
        return np.array([self.x], dtype=np.float32), -abs(self.x - 1.0), abs(self.x - 1.0) < 0.05, False, {}

    def render(self):
        frame = np.zeros((8, 16, 3), dtype=np.uint8)
        frame[:, int(np.clip((self.x + 2) * 4, 0, 15))] = 255
        return frame


gym.register("Reach1D-v0", entry_point=Reach1D, max_episode_steps=30)
'''

#: A module that must never be imported: it leaves a file behind if it is.
EVIL_MODULE = """
from pathlib import Path
Path(__file__).with_name("IMPORTED").write_text("code ran")
"""


def one_error_line(err: str, prefix: str = "imix") -> str:
    """The single line a refusal prints (no traceback)."""
    lines = [line for line in err.strip().splitlines() if line.strip()]
    assert len(lines) == 1 and lines[0].startswith(prefix) and "Traceback" not in err, err
    return lines[0]


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    root = tmp_path_factory.mktemp("results")
    assert main(["run", *TINY, f"results_dir={root}", "experiment=e"]) == 0
    return root, root / "e" / RUN


@pytest.fixture
def copied(trained, tmp_path):
    """A fresh copy of the trained experiment, to be damaged by one test."""
    import shutil

    root, _ = trained
    shutil.copytree(root / "e", tmp_path / "e")
    return tmp_path, tmp_path / "e" / RUN


def rewrite_policy(path, **changes):
    """Rewrite a policy file with header fields changed (or params, with ``params=``): a well-formed forgery."""
    policy = read_policy(path)
    params = changes.pop("params", policy.params)
    write_policy(path, params, {**policy.header, **changes})


# ------------------------------------------------------------------ 1. no module named in a file is imported
@pytest.mark.parametrize("command", ["eval", "render"])
def test_a_module_named_in_a_policy_file_is_never_imported(copied, tmp_path, monkeypatch, capsys, command):
    root, run_dir = copied
    (tmp_path / "evil_module.py").write_text(EVIL_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    rewrite_policy(policy_path(run_dir, 0, "mean"), env_id="evil_module:CartPole-v0", env_name="evil_module:CartPole-v0")
    capsys.readouterr()
    extra = [f"out={tmp_path / 'p.gif'}"] if command == "render" else []
    assert main([command, f"results_dir={root}", "experiment=e", *extra]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert "evil_module" in line and "import" in line
    assert not (tmp_path / "IMPORTED").exists() and "evil_module" not in sys.modules


def test_this_in_a_policy_header_does_not_print_the_zen_of_python(copied, capfd):
    root, run_dir = copied
    rewrite_policy(policy_path(run_dir, 0, "mean"), env_id="this:CartPole-v0")
    already = "this" in sys.modules
    assert main(["render", f"results_dir={root}", "experiment=e", f"out={root / 'p.gif'}"]) == 1
    out, err = capfd.readouterr()
    assert "Beautiful is better" not in out + err and ("this" in sys.modules) == already
    assert "import" in one_error_line(err)


def test_a_module_named_on_the_command_line_must_be_the_files(copied, tmp_path, monkeypatch, capsys):
    """import=X lets a file name module X, and only X."""
    root, run_dir = copied
    (tmp_path / "evil_module.py").write_text(EVIL_MODULE)
    monkeypatch.syspath_prepend(str(tmp_path))
    rewrite_policy(policy_path(run_dir, 0, "mean"), env_id="evil_module:CartPole-v0", env_name="evil_module:CartPole-v0")
    assert main(["eval", f"results_dir={root}", "experiment=e", "import=json"]) == 1
    assert "evil_module" in one_error_line(capsys.readouterr().err)
    assert not (tmp_path / "IMPORTED").exists()


def _imix(args, env, cwd):
    return subprocess.run([sys.executable, "-m", "imix_cli.commands.cli", *args], env=env, cwd=cwd, capture_output=True, text=True, timeout=300)


@pytest.mark.slow
def test_a_user_env_by_module_id_runs_evaluates_and_renders_but_only_imports_what_the_user_names(tmp_path):
    """``env.id=myenvs:Reach1D-v0`` typed by the user: run imports myenvs; eval/render import it only
    when the user names it again (``import=myenvs``), never because a file in the run folder says so."""
    (tmp_path / "myenvs.py").write_text(USER_ENV_MODULE)
    log = tmp_path / "imports.log"
    repo = Path(__file__).resolve().parent.parent
    env = {**os.environ, "PYTHONPATH": os.pathsep.join([str(repo), str(tmp_path)]), "IMIX_TEST_IMPORT_LOG": str(log)}
    results = f"results_dir={tmp_path / 'R'}"
    ran = _imix(["run", "algo=cem", "env=gym", "env.id=myenvs:Reach1D-v0", "seeds=2", "generations=3", "popsize=6", "progress=false", results], env, tmp_path)
    assert ran.returncode == 0, ran.stderr
    (run_dir,) = (tmp_path / "R" / "default").iterdir()
    assert run_dir.name == "cem-Reach1D-v0-none-popsize=6" and "myenvs" in log.read_text()
    assert "myenvs:Reach1D-v0" in (run_dir / "config.yaml").read_text()  # what eval/render need to know
    assert read_policy(policy_path(run_dir, 0, "mean")).header["env_id"] == "myenvs:Reach1D-v0"

    log.unlink()
    for command in (["eval"], ["render", f"out={tmp_path / 'r.gif'}"]):
        refused = _imix([*command, results], env, tmp_path)
        assert refused.returncode == 1
        line = one_error_line(refused.stderr)
        assert "import=myenvs" in line  # says how to allow it
        assert not log.exists()  # the module was not imported
    evaluated = _imix(["eval", results, "import=myenvs", "episodes=3"], env, tmp_path)
    assert evaluated.returncode == 0, evaluated.stderr
    assert (run_dir / "eval.csv").exists() and log.read_text().count("myenvs") == 1
    rendered = _imix(["render", results, "import=myenvs", f"out={tmp_path / 'r.gif'}"], env, tmp_path)
    assert rendered.returncode == 0, rendered.stderr
    assert (tmp_path / "r.gif").stat().st_size > 0


# ------------------------------------------------------------------ 3. zip bombs: sizes checked before inflating
def npy_header(shape, descr="<f8") -> bytes:
    buffer = io.BytesIO()
    np.lib.format.write_array_header_1_0(buffer, {"descr": descr, "fortran_order": False, "shape": shape})
    return buffer.getvalue()


def bomb_zip(path, members: dict) -> None:
    """Write a zip whose members (name -> (prefix bytes, number of zero bytes after it)) are deflated.

    A run of zeros deflates ~1000:1, so a 1 MB file can declare a gigabyte. Built by hand (each
    1 MiB block of zeros compresses to the same bytes after a full flush), so the test takes no
    more than a second to make it.
    """
    chunk = bytes(1 << 20)
    local, central, offset = [], [], 0
    for name, (prefix, zeros) in members.items():
        c = zlib.compressobj(9, zlib.DEFLATED, -15)
        parts = [c.compress(prefix) + c.flush(zlib.Z_FULL_FLUSH)]
        crc = zlib.crc32(prefix)
        if zeros >= len(chunk):
            block = c.compress(chunk) + c.flush(zlib.Z_FULL_FLUSH)
            parts.append(block * (zeros // len(chunk)))
            for _ in range(zeros // len(chunk)):
                crc = zlib.crc32(chunk, crc)
        rest = bytes(zeros % len(chunk))
        parts.append(c.compress(rest) + c.flush(zlib.Z_FINISH))
        crc = zlib.crc32(rest, crc)
        data, size, raw = b"".join(parts), len(prefix) + zeros, name.encode()
        head = struct.pack("<IHHHHHIIIHH", 0x04034B50, 20, 0, 8, 0, 0x21, crc, len(data), size, len(raw), 0) + raw
        central.append(struct.pack("<IHHHHHHIIIHHHHHII", 0x02014B50, 20, 20, 0, 8, 0, 0x21, crc, len(data), size, len(raw), 0, 0, 0, 0, 0, offset) + raw)
        local.append(head + data)
        offset += len(head) + len(data)
    directory = b"".join(central)
    end = struct.pack("<IHHHHIIH", 0x06054B50, 0, 0, len(central), len(central), len(directory), offset, 0)
    Path(path).write_bytes(b"".join(local) + directory + end)


def members_of(path) -> dict:
    """A real .npz's members as bomb_zip() takes them (their bytes, no zeros)."""
    with zipfile.ZipFile(path) as z:
        return {name: (z.read(name), 0) for name in z.namelist()}


GIB = 1 << 30

# VmHWM, not getrusage's ru_maxrss: Linux carries ru_maxrss over exec from the forking process (here,
# pytest, which may be large), while VmHWM is the peak of this process's own address space.
PEAK_RSS = """
import re, sys
sys.path[:0] = {paths!r}
{code}
print(int(re.search(r"VmHWM:\\s+(\\d+) kB", open("/proc/self/status").read()).group(1)) // 1024)
"""


def peak_rss_mib(code: str, tmp_path) -> tuple[int, str]:
    """Run ``code`` in a fresh interpreter; its peak RSS in MiB and its stdout before that number."""
    repo = str(Path(__file__).resolve().parent.parent)
    script = PEAK_RSS.format(paths=[repo], code=textwrap.dedent(code))
    proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=300, cwd=tmp_path)
    assert proc.returncode == 0, proc.stderr
    *out, peak = proc.stdout.strip().splitlines()
    return int(peak), "\n".join(out)


def test_a_policy_zip_bomb_is_refused_before_inflating(copied, tmp_path):
    _, run_dir = copied
    path = policy_path(run_dir, 0, "mean")
    members = members_of(path)
    members["params.npy"] = (npy_header((GIB // 8,)), GIB)  # 1 GiB of declared zeros
    bomb_zip(path, members)
    assert path.stat().st_size < 2 << 20
    peak, out = peak_rss_mib(
        f"""
        from imix_cli.running.files.policy_files import PolicyFileError, read_policy
        try:
            read_policy({str(path)!r})
        except PolicyFileError as err:
            print("refused:", err)
        """,
        tmp_path,
    )
    assert peak < 400, f"peak RSS {peak} MiB reading a 1 GiB policy bomb"
    assert out.startswith("refused:") and "bytes" in out


@pytest.mark.slow
def test_a_checkpoint_zip_bomb_is_refused_before_inflating(tmp_path):
    root = tmp_path / "R"
    args = ["run", "algo=cem", "env=cartpole", "seeds=1", "generations=4", "popsize=6", "checkpoint_every=2", "checkpoint_seconds=0",
            "eim=true", "progress=false", "workers=1"]  # fmt: skip
    assert main([*args, f"results_dir={root}"]) == 0
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / ".checkpoints" / "seed_0.npz"
    members = members_of(path)
    name = next(n for n in members if n.endswith("/samples.npy"))
    members[name] = (npy_header((GIB // 8 // 130, 130)), GIB // 8 // 130 * 130 * 8)
    bomb_zip(path, members)
    assert path.stat().st_size < 2 << 20
    peak, out = peak_rss_mib(
        f"""
        from imix_cli.running.config.compose import validate_overrides
        from imix_cli.core.evaluation import make_evaluator
        from imix_cli.running.loop.lockstep import loop_settings, new_seed_state
        from imix_cli.running.loop.resume import load_checkpoint
        (spec,) = validate_overrides({[*args[1:], "generations=6", f"results_dir={root}"]!r})
        fresh = new_seed_state(loop_settings(spec, make_evaluator("cartpole")), 0)
        from imix_cli.running.config.run_spec import resume_identity
        st = load_checkpoint(spec.run_dir, 0, resume_identity(spec.identity()), fresh, warn=lambda m: print("refused:", m), spec=spec)
        assert st is None
        """,
        tmp_path,
    )
    assert peak < 400, f"peak RSS {peak} MiB reading a 1 GiB checkpoint bomb"
    assert out.startswith("refused:") and "bytes" in out


# ------------------------------------------------------------------ 4. checkpoints forged with a recomputed checksum
FORGE_RUN = ["run", "algo=cem", "env=cartpole", "seeds=1", "popsize=6", "checkpoint_every=2", "checkpoint_seconds=0", "eim=true", "progress=false", "workers=1"]


def forge_checkpoint(path, change) -> None:
    """Rewrite a checkpoint with ``change(header, arrays)`` applied and its checksum recomputed: a forgery
    that passes every integrity check, only the values are wrong."""
    from imix_cli.running.files import checkpoints

    with np.load(path, allow_pickle=False) as npz:
        arrays = {name: npz[name] for name in npz.files}
    header = json.loads(arrays.pop("header").tobytes())
    header.pop("checksum")
    change(header, arrays)
    header["checksum"] = checkpoints._checksum(header, arrays)
    buffer = io.BytesIO()
    np.savez(buffer, header=np.frombuffer(checkpoints._canonical(header).encode(), dtype=np.uint8), **arrays)
    Path(path).write_bytes(buffer.getvalue())


def _drop_last_row(header, arrays):
    table = header["state"]["state"]["rows"]["table"]
    for kind in ("int", "float"):
        arrays[table[kind]] = arrays[table[kind]][:, :-1]
    for column in table["columns"]:
        if "str" in column:
            column["str"].pop()


def _set_row(header, arrays, index, **values):
    """Set values of row ``index`` of the checkpoint's rows (a table: checkpoints._encode_table). A value its
    column's array cannot hold (a string in an int column) turns the column into a list of values."""
    table = header["state"]["state"]["rows"]["table"]
    for key, value in values.items():
        i = table["keys"].index(key)
        ((kind, where),) = table["columns"][i].items()
        matrix = arrays[table[kind]]
        if isinstance(value, (int, float)):
            matrix[where, index] = value
        else:
            column = matrix[where].tolist()
            column[index] = value
            table["columns"][i] = {"list": column}


def _state(header):
    return header["state"]["state"]


def _set_array(arrays, name, value):
    arrays[name] = value


FORGERIES = {
    "a row's mean_score": lambda h, a: _set_row(h, a, 1, mean_score=1234.5, best_score=1234.5),
    "best_params of the wrong size": lambda h, a: _set_array(a, "best_params", np.zeros(7)),
    "NaN weights and train_return 1e300": lambda h, a: (_set_array(a, "best_params", np.full(130, np.nan)), _state(h).update(best_return=1e300)),
    "a wrong archive shape": lambda h, a: _set_array(a, "archive/generations/0/samples", np.zeros((3, 130))),
    "a string counter": lambda h, a: _state(h).update(evaluations=str(_state(h)["evaluations"])),
    "a string counter in a row": lambda h, a: _set_row(h, a, 0, evaluations="6"),
    "episodes that decrease": lambda h, a: _set_row(h, a, 1, evaluations=1),
    "a row dropped": lambda h, a: _drop_last_row(h, a),
    "an ES generation count": lambda h, a: h["state"]["state"]["es"]["es"]["dict"].update(generation=99),
    "a NaN distribution mean": lambda h, a: _set_array(a, "es/mean", np.full(130, np.nan)),
    "archive sources out of range": lambda h, a: _set_array(a, "archive/generations/0/source", np.full(6, 9)),
    "a negative elapsed time": lambda h, a: _state(h).update(elapsed=-5.0),
    "a float counter": lambda h, a: _state(h).update(env_steps=float(_state(h)["env_steps"])),
}


@pytest.fixture(scope="module")
def reference_csv(tmp_path_factory):
    """The CSV of the forged runs' config, run at once: what a refused checkpoint must still give."""
    root = tmp_path_factory.mktemp("reference")
    assert main([*FORGE_RUN, "generations=6", f"results_dir={root}"]) == 0
    (run_dir,) = (root / "default").iterdir()
    return (run_dir / "seed_0.csv").read_text()


@pytest.mark.parametrize("forgery", list(FORGERIES))
def test_a_forged_checkpoint_is_refused_and_the_seed_restarts(tmp_path, capfd, reference_csv, forgery):
    """A finished run keeps its final state to be continued; forged (checksum recomputed), it is refused
    with one warning and the seed restarts, giving exactly the CSV of an honest run -- no traceback."""
    assert main([*FORGE_RUN, "generations=4", f"results_dir={tmp_path}"]) == 0
    (run_dir,) = (tmp_path / "default").iterdir()
    forge_checkpoint(run_dir / ".checkpoints" / "seed_0.npz", FORGERIES[forgery])
    capfd.readouterr()
    assert main([*FORGE_RUN, "generations=6", f"results_dir={tmp_path}"]) == 0
    err = capfd.readouterr().err
    warnings = [line for line in err.splitlines() if "checkpoint ignored" in line]
    assert len(warnings) == 1 and "restarts from scratch" in warnings[0] and "Traceback" not in err, err
    assert _same_numbers(run_dir / "seed_0.csv", reference_csv)


def _same_numbers(path, reference: str) -> bool:
    """Equal CSVs but for wall_time (the one column that depends on the clock)."""
    import pandas as pd

    got, want = pd.read_csv(path), pd.read_csv(io.StringIO(reference))
    return got.drop(columns="wall_time").equals(want.drop(columns="wall_time"))


# ------------------------------------------------------------------ 2. symlinks in the checkpoint area are refused
@pytest.mark.parametrize("link", [".checkpoints", ".checkpoints/seed_0.npz"])
def test_a_symlink_in_the_checkpoint_area_is_refused_not_followed(tmp_path, capsys, link):
    """A ``.checkpoints`` symlink would send checkpoints elsewhere and delete ``.*.tmp`` files there; a
    symlinked checkpoint would be read from elsewhere. Both: one line, exit 1, the target untouched."""
    victim = tmp_path / "victim"
    victim.mkdir()
    (victim / ".precious.tmp").write_text("keep me")
    (victim / "seed_0.npz").write_text("not a checkpoint")
    run_dir = tmp_path / "R" / "default" / "cem-cartpole-none-popsize=6"
    (run_dir / ".checkpoints").mkdir(parents=True)
    if link == ".checkpoints":
        (run_dir / ".checkpoints").rmdir()
        (run_dir / ".checkpoints").symlink_to(victim, target_is_directory=True)
    else:
        (run_dir / link).symlink_to(victim / "seed_0.npz")
    before = sorted((p.name, p.read_text()) for p in victim.iterdir())
    capsys.readouterr()
    assert main(["run", *TINY[:3], "generations=4", "popsize=6", "checkpoint_every=1", "checkpoint_seconds=0",
                 "progress=false", "workers=1", f"results_dir={tmp_path / 'R'}"]) == 1  # fmt: skip
    line = one_error_line(capsys.readouterr().err)
    assert "link" in line and ".checkpoints" in line
    assert sorted((p.name, p.read_text()) for p in victim.iterdir()) == before
    assert not (run_dir / "seed_0.csv").exists()


# ------------------------------------------------------------------ 10. seed CSVs: one validation for run, plot and status
@pytest.fixture(scope="module")
def two_seeds(tmp_path_factory):
    root = tmp_path_factory.mktemp("two")
    assert main(["run", *TINY[:2], "seeds=2", "generations=3", "popsize=6", "progress=false", "workers=1", f"results_dir={root}", "experiment=e"]) == 0
    return root


def _copy_experiment(root, tmp_path):
    import shutil

    shutil.copytree(root / "e", tmp_path / "e")
    return tmp_path / "e" / RUN


@pytest.mark.parametrize("edit_seed_column", [False, True])
def test_plot_does_not_count_a_copied_seed_csv_twice(two_seeds, tmp_path, edit_seed_column):
    from imix_cli.plotting.data import load_experiment

    run_dir = _copy_experiment(two_seeds, tmp_path)
    text = (run_dir / "seed_1.csv").read_text()
    if edit_seed_column:  # the copy made to look like seed 0: its rows are still seed 1's
        import pandas as pd

        frame = pd.read_csv(io.StringIO(text))
        frame["seed"] = 0
        text = frame.to_csv(index=False, float_format="%.10g", lineterminator="\n")
    (run_dir / "seed_0.csv").write_text(text)
    warnings = []
    (group,) = load_experiment(tmp_path, "e", warn=warnings.append).groups
    assert group.n_seeds == 1, "a copied CSV counted as a second seed"
    copies = [w for w in warnings if "copy" in w]  # (the other warning: fewer seeds than config.yaml asks for)
    assert len(copies) == 1 and "seed_0" in copies[0], warnings


def test_run_refuses_a_seed_csv_whose_evaluations_decrease_as_plot_does(two_seeds, tmp_path, capsys):
    import pandas as pd

    run_dir = _copy_experiment(two_seeds, tmp_path)
    frame = pd.read_csv(run_dir / "seed_0.csv")
    frame.loc[2, "evaluations"] = 1
    frame.to_csv(run_dir / "seed_0.csv", index=False)
    capsys.readouterr()
    assert main(["run", *TINY[:2], "seeds=2", "generations=3", "popsize=6", "progress=false", "workers=1", f"results_dir={tmp_path}", "experiment=e"]) == 1
    line = one_error_line(capsys.readouterr().err)
    assert "seed_0.csv" in line and "evaluations" in line


# ------------------------------------------------------------------ 10. eval: bad policy files are one line
BAD_HEADERS = {
    "obs_dim a string": {"obs_dim": "4"},
    "obs_dim negative": {"obs_dim": -4},
    "obs_dim a float": {"obs_dim": 4.0},
    "hidden a string": {"hidden": "8,8"},
    "hidden huge": {"hidden": [10**9]},
    "hidden negative": {"hidden": [-8, 8]},
    "discrete a string": {"discrete": "yes"},
    "max_steps 1e12": {"max_steps": 10**12},
    "max_steps a float": {"max_steps": 1e12},
    "max_steps above the run's cap": {"max_steps": 250},
    "max_steps zero": {"max_steps": 0},
    "seed negative": {"seed": -1},
    "seed a string": {"seed": "0"},
    "env_id a number": {"env_id": 5},
    "env_name null": {"env_name": None},
    "env_id unknown": {"env_name": "Nope-v9", "env_id": "Nope-v9"},
    "env_id of another env": {"env_id": "Acrobot-v1"},
    "action bounds on a discrete env": {"action_low": [0.0], "action_high": [1.0]},
    "which unknown": {"which": "worst"},
    "format unknown": {"format": "imix-policy/9"},
    "out_dim not the env's": {"out_dim": 3},
    "train_return a string": {"train_return": "inf"},
    "generation negative": {"generation": -1},
    "obs_normalizer a string": {"obs_normalizer": "x"},
}


@pytest.mark.parametrize("case", list(BAD_HEADERS))
def test_eval_refuses_a_bad_policy_header_in_one_line(copied, capsys, case):
    root, run_dir = copied
    path = policy_path(run_dir, 0, "mean")
    policy = read_policy(path)
    header = {**policy.header, **BAD_HEADERS[case]}
    params = policy.params
    if case == "out_dim not the env's":  # the right number of weights for that header: only the env disagrees
        params = np.zeros(4 * 8 + 8 + 8 * 8 + 8 + 8 * 3 + 3)
    write_policy(path, params, header)
    capsys.readouterr()
    assert main(["eval", f"results_dir={root}", "experiment=e", "episodes=2"]) == 1
    one_error_line(capsys.readouterr().err, "imix eval:")


def _raw_policy(path, header_text: str, params) -> None:
    buffer = io.BytesIO()
    np.savez(buffer, params=params, header=np.array(header_text))
    Path(path).write_bytes(buffer.getvalue())


@pytest.mark.parametrize(
    "case", ["not JSON", "a JSON list", "deeply nested", "params of strings", "params 2-D", "params int", "header bytes", "no params", "extra member"]
)
def test_eval_refuses_a_malformed_policy_file_in_one_line(copied, capsys, case):
    root, run_dir = copied
    path = policy_path(run_dir, 0, "mean")
    policy = read_policy(path)
    text = json.dumps(policy.header)
    if case == "not JSON":
        _raw_policy(path, text[:-3], policy.params)
    elif case == "a JSON list":
        _raw_policy(path, json.dumps([policy.header]), policy.params)
    elif case == "deeply nested":
        _raw_policy(path, "[" * 100_000 + "]" * 100_000, policy.params)
    elif case == "params of strings":
        _raw_policy(path, text, np.array(["1.0"] * 130))
    elif case == "params 2-D":
        _raw_policy(path, text, policy.params.reshape(10, 13))
    elif case == "params int":
        _raw_policy(path, text, np.zeros(130, dtype=np.int64))
    elif case == "header bytes":
        buffer = io.BytesIO()
        np.savez(buffer, params=policy.params, header=np.frombuffer(text.encode(), dtype=np.uint8))
        path.write_bytes(buffer.getvalue())
    elif case == "no params":
        buffer = io.BytesIO()
        np.savez(buffer, header=np.array(text))
        path.write_bytes(buffer.getvalue())
    else:
        buffer = io.BytesIO()
        np.savez(buffer, params=policy.params, header=np.array(text), extra=np.zeros(3))
        path.write_bytes(buffer.getvalue())
    capsys.readouterr()
    assert main(["eval", f"results_dir={root}", "experiment=e", "episodes=2"]) == 1
    one_error_line(capsys.readouterr().err, "imix eval:")


@pytest.mark.parametrize("value", [np.nan, np.inf, -np.inf])
def test_eval_refuses_non_finite_weights_instead_of_scoring_them(copied, capsys, value):
    root, run_dir = copied
    path = policy_path(run_dir, 0, "mean")
    policy = read_policy(path)
    params = policy.params.copy()
    params[5] = value
    write_policy(path, params, policy.header)
    capsys.readouterr()
    assert main(["eval", f"results_dir={root}", "experiment=e", "episodes=2"]) == 1
    assert "NaN or infinite" in one_error_line(capsys.readouterr().err, "imix eval:")
    assert not (run_dir / "eval.csv").exists()


def test_eval_bounds_episodes_and_runs_them_in_batches(copied, capsys, monkeypatch):
    """``episodes=1000000000`` is one line (it would take days), and any episodes= runs in batches whose
    memory does not grow with it -- with the same statistics as one batch."""
    from imix_cli.commands import eval_command

    root, run_dir = copied
    assert main(["eval", f"results_dir={root}", "experiment=e", "episodes=1000000000"]) == 2
    assert "episodes" in one_error_line(capsys.readouterr().err, "imix eval:")

    policy = read_policy(policy_path(run_dir, 0, "mean"))
    whole = eval_command.evaluate_policy(policy, 1000)
    sizes = []
    real = eval_command.evaluator_for

    def recording(*args, **kwargs):
        evaluator = real(*args, **kwargs)

        class Recorder:
            def __getattr__(self, name):
                return getattr(evaluator, name)

            def evaluate(self, params, seeds):
                sizes.append(len(params))
                return evaluator.evaluate(params, seeds)

        return Recorder()

    monkeypatch.setattr(eval_command, "evaluator_for", recording)
    monkeypatch.setattr(eval_command, "_MAX_BATCH", 64)
    batched = eval_command.evaluate_policy(policy, 1000)
    assert max(sizes) == 64 and sum(sizes) == 1000
    assert batched["mean"] == pytest.approx(whole["mean"], rel=1e-12) and batched["std"] == pytest.approx(whole["std"], rel=1e-9)
    assert (batched["min"], batched["max"], batched["mean_steps"]) == (whole["min"], whole["max"], whole["mean_steps"])


def test_eval_of_a_read_only_results_folder_prints_the_numbers_and_one_line(copied, capsys, monkeypatch):
    import imix_cli.running.files.writing as writing_module

    root, run_dir = copied

    def read_only(path, text, **_):
        raise PermissionError(13, "Permission denied", str(path))

    monkeypatch.setattr(writing_module, "atomic_write_text", read_only)  # as in a read-only folder (root ignores chmod)
    assert main(["eval", f"results_dir={root}", "experiment=e", "episodes=2"]) == 1
    out, err = capsys.readouterr()
    assert RUN in out and "95% CI" in out
    assert "eval.csv" in one_error_line(err, "imix eval:")


def test_a_seed_csv_holding_another_seeds_rows_is_refused_by_the_reader(two_seeds, tmp_path):
    """The reader run, plot and status share refuses a copy under another seed's name (its seed column
    says whose rows they are), so ``imix run`` does not take seed 1's rows as seed 0's result either."""
    from imix_cli.running.files.results import CorruptResultError, read_run_csv

    run_dir = _copy_experiment(two_seeds, tmp_path)
    (run_dir / "seed_0.csv").write_text((run_dir / "seed_1.csv").read_text())
    with pytest.raises(CorruptResultError, match=r"seed_0\.csv: its rows are of seed \[1\].*a copy"):
        read_run_csv(run_dir / "seed_0.csv")
    read_run_csv(run_dir / "seed_1.csv")  # the original is fine


# ------------------------------------------------------------------ not a file: /dev/zero, a FIFO
READ_SPECIAL = """
import sys
sys.path[:0] = {paths!r}
from imix_cli.running.files.checkpoints import CheckpointError, read_checkpoint
from imix_cli.running.files.policy_files import PolicyFileError, read_policy
from imix_cli.running.files.results import CorruptResultError, read_run_csv
from imix_cli.running.run_folder import RunError, prepare_run_dir
name, target = {name!r}, {target!r}
try:
    if name == "seed_0.csv":
        read_run_csv(target)
    elif name == "policy_0_mean.npz":
        read_policy(target)
    elif name == "config.yaml":
        from imix_cli.running.config.compose import validate_overrides

        (spec,) = validate_overrides({overrides!r})
        prepare_run_dir(spec)
    else:
        read_checkpoint(target, None, identity={{}}, seed=0)
except (CheckpointError, PolicyFileError, CorruptResultError, RunError) as err:
    print("refused:", err)
"""


def _limited():
    import resource

    resource.setrlimit(resource.RLIMIT_AS, (3 << 30, 3 << 30))  # a reader that reads forever fails here, not the machine


def plant_special(target, special):
    """Put ``/dev/zero`` (as a symlink) or a FIFO where a file of imix's is expected; return the path."""
    target.parent.mkdir(exist_ok=True)
    target.unlink(missing_ok=True)
    if special == "fifo":
        os.mkfifo(target)
    else:
        target.symlink_to(special)
    return target


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
@pytest.mark.parametrize("name", ["seed_0.csv", "policy_0_mean.npz", "config.yaml", ".checkpoints/seed_0.npz"])
def test_a_file_that_is_a_device_or_a_fifo_is_refused_without_reading_it(copied, tmp_path, special, name):
    """``/dev/zero`` never ends and a FIFO blocks: a reader that opened either would take all the memory
    or hang. Every reader requires a regular file (one line), and never starts reading anything else.
    (Run in a subprocess with a 3 GiB address-space limit and a 60 s timeout: the readers before this
    check read /dev/zero until the machine ran out of memory.)"""
    root, run_dir = copied
    target = plant_special(run_dir / name, special)
    repo = str(Path(__file__).resolve().parent.parent)
    script = READ_SPECIAL.format(paths=[repo], name=name, target=str(target), overrides=[*TINY, f"results_dir={root}", "experiment=e"])
    try:
        proc = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True, timeout=60, preexec_fn=_limited)
    except subprocess.TimeoutExpired:
        pytest.fail(f"reading a {special} as {name} hangs")
    # a symlink inside a run folder is refused as a link before anything is opened (imix_cli.running.run_folder.refuse_links)
    refused_as = ("not a regular file", "symbolic link")
    assert proc.returncode == 0 and proc.stdout.startswith("refused:") and any(r in proc.stdout for r in refused_as), proc.stdout + proc.stderr[-500:]


@pytest.mark.parametrize("change", [{"max_steps": 10**12}, {"env_id": "this:CartPole-v0"}, {"params": "nan"}])
def test_render_refuses_what_eval_refuses(copied, tmp_path, capsys, change):
    root, run_dir = copied
    path = policy_path(run_dir, 0, "mean")
    policy = read_policy(path)
    params = policy.params.copy()
    if change.get("params") == "nan":
        params[0] = np.nan
        change = {}
    write_policy(path, params, {**policy.header, **change})
    capsys.readouterr()
    assert main(["render", f"results_dir={root}", "experiment=e", f"out={tmp_path / 'p.gif'}"]) == 1
    one_error_line(capsys.readouterr().err, "imix render:")
    assert not (tmp_path / "p.gif").exists()


@pytest.mark.parametrize("special", ["/dev/zero", "fifo"])
@pytest.mark.parametrize("name", ["config.yaml", ".checkpoints/seed_0.json", ".checkpoints/seed_0.npz"])
def test_status_reads_no_device_or_fifo(copied, special, name):
    """``imix status`` is read-only and safe while runs write: a config.yaml or checkpoint that is /dev/zero
    or a FIFO must neither fill the memory nor block it (3 GiB address-space limit, 60 s timeout)."""
    root, run_dir = copied
    plant_special(run_dir / name, special)
    env = {**os.environ, "PYTHONPATH": str(Path(__file__).resolve().parent.parent)}
    try:
        proc = subprocess.run([IMIX, "status", f"results_dir={root}", "experiment=e"], capture_output=True, text=True, timeout=60, preexec_fn=_limited, env=env)
    except subprocess.TimeoutExpired:
        pytest.fail(f"imix status blocks on a {special} as {name}")
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr[-800:]
    assert RUN in proc.stdout, proc.stdout

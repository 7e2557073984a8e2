"""Every reader of a file imix reads back, fed 1,000+ random mutations of a real file: 0 tracebacks, 0 hangs,
0 silently changed numbers.

A seeded mutator (no extra dependency; a failure names its seed and mutation, so it replays) makes
two kinds of damage from a real file of each kind -- checkpoint, policy file, seed CSV, config.yaml:

* **accidents** on the bytes: bit flips, random bytes, truncation, deleted/inserted/duplicated ranges,
  a digit changed. The oracle: the reader refuses (its one-line error class) or returns *exactly*
  the original content. For checkpoints and policy files (zips: CRC-32 per member, and a SHA-256
  over a checkpoint's content) this holds for any such damage.
* **forgeries** of the payload: a ``.npy`` member or the JSON header rewritten -- a number changed,
  a field retyped, a shape changed -- and the zip rebuilt with valid CRCs. A checkpoint's checksum
  still catches these (nobody recomputes it by chance); a policy file or CSV has no checksum, so the
  oracle there is that what is accepted passes every validation (types, shapes, finite values in
  range): a forged value can be accepted only if it is one the file could legitimately hold.

A seed CSV or config.yaml is text with no checksum: a digit changed inside a score is a different,
valid file, which no reader can tell from the original. For them the oracle is: refused, or every
invariant of the contract holds (and for config.yaml: a run goes on only if the config's identity
is unchanged).

Each call runs under an alarm (a hang fails the test). Counts are kept per outcome and printed.
"""

from __future__ import annotations

import contextlib
import io
import json
import random
import signal
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from imix_cli.commands.cli import main
from imix_cli.core.evaluation import make_evaluator
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.config.run_spec import resume_identity
from imix_cli.running.files.checkpoints import CheckpointError, _canonical, _encode, read_checkpoint
from imix_cli.running.files.policy_files import PolicyFileError, num_params_of, read_policy
from imix_cli.running.files.results import COLUMNS, CorruptResultError, read_run_csv
from imix_cli.running.loop.lockstep import loop_settings, new_seed_state
from imix_cli.running.loop.resume import checkpoint_byte_limit, validate_seed_state
from imix_cli.running.run_folder import RunError, prepare_run_dir

MUTATIONS = 1000
INT_COLUMNS = (
    "seed", "generation", "evaluations", "env_steps", "reused", "reused_im", "reused_eim", "reevaluated", "popsize", "nonfinite",
    "mean_policy_episodes", "diverged",
)  # fmt: skip
ARGS = ["algo=cem", "env=cartpole", "seeds=1", "generations=4", "popsize=6", "checkpoint_every=2", "checkpoint_seconds=0",
        "eim=true", "progress=false", "workers=1"]  # fmt: skip


class Hang(Exception):
    pass


@contextlib.contextmanager
def deadline(seconds: float):
    """Raise :class:`Hang` if the block takes longer than ``seconds``."""

    def expire(signum, frame):
        raise Hang

    old = signal.signal(signal.SIGALRM, expire)
    signal.setitimer(signal.ITIMER_REAL, seconds)
    try:
        yield
    finally:
        signal.setitimer(signal.ITIMER_REAL, 0)
        signal.signal(signal.SIGALRM, old)


# ------------------------------------------------------------------------------- the mutator
def mutate_bytes(data: bytes, rng: random.Random) -> tuple[bytes, str]:
    """One accident on ``data``: returns the damaged bytes and what was done (for a failure message)."""
    n = len(data)
    i, j = sorted((rng.randrange(n), rng.randrange(n)))
    kind = rng.choice(["flip", "byte", "truncate", "delete", "insert", "duplicate", "digit", "zero"])
    if kind == "flip":
        b = bytearray(data)
        b[i] ^= 1 << rng.randrange(8)
        return bytes(b), f"flip bit at {i}"
    if kind == "byte":
        b = bytearray(data)
        b[i] = rng.randrange(256)
        return bytes(b), f"byte {i} = {b[i]}"
    if kind == "truncate":
        return data[:i], f"truncate at {i}"
    if kind == "delete":
        return data[:i] + data[j + 1 :], f"delete {i}..{j}"
    if kind == "insert":
        return data[:i] + bytes(rng.randrange(256) for _ in range(rng.randint(1, 16))) + data[i:], f"insert at {i}"
    if kind == "duplicate":
        return data[:j] + data[i:j] + data[j:], f"duplicate {i}..{j}"
    if kind == "zero":
        return data[:i] + bytes(min(j - i, 64)) + data[i + min(j - i, 64) :], f"zero {i}.."
    digits = [k for k, c in enumerate(data) if 48 <= c <= 57]
    if not digits:
        return data[:i], f"truncate at {i}"
    k = rng.choice(digits)
    b = bytearray(data)
    b[k] = 48 + (b[k] - 48 + rng.randint(1, 9)) % 10
    return bytes(b), f"digit at {k}"


def mutate_text_value(text: str, rng: random.Random) -> tuple[str, str]:
    """A forgery of a JSON text: one scalar replaced by a number, a string, null, a list or a huge value."""
    replacements = ["0", "-1", "1e300", "NaN", "Infinity", '"x"', "null", "[]", "{}", "true", "123456789012345678901234567890", "0.5", '"' + "a" * 50 + '"']
    value = rng.choice(replacements)
    spots = [k for k, c in enumerate(text) if c == ":"]
    k = rng.choice(spots) + 1
    end = k
    while end < len(text) and text[end] not in ",}]":
        end += 1
    if end - k > 400:  # a nested object: replace it whole only sometimes
        end = k
    return text[:k] + value + text[end:], f"value after char {k} -> {value[:20]}"


def npz_members(data: bytes) -> dict:
    with zipfile.ZipFile(io.BytesIO(data)) as z:
        return {name: z.read(name) for name in z.namelist()}


def rebuild_npz(members: dict) -> bytes:
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as z:
        for name, raw in members.items():
            z.writestr(name, raw)
    return buffer.getvalue()


def npy_bytes(array) -> bytes:
    buffer = io.BytesIO()
    np.save(buffer, array, allow_pickle=False)
    return buffer.getvalue()


def forge_npz(data: bytes, rng: random.Random, header_member: str, header_is_bytes: bool) -> tuple[bytes, str]:
    """A forgery: one member's array or the JSON header rewritten, the zip rebuilt with valid CRCs."""
    members = npz_members(data)
    name = rng.choice(sorted(members))
    array = np.load(io.BytesIO(members[name]), allow_pickle=False)
    if name == header_member:
        text = array.tobytes().decode() if header_is_bytes else str(array[()])
        text, what = mutate_text_value(text, rng)
        new = np.frombuffer(text.encode(), dtype=np.uint8) if header_is_bytes else np.array(text)
    else:
        kind = rng.choice(["value", "nan", "shape", "dtype", "empty", "huge"])
        what = f"{name}: {kind}"
        if kind == "value" and array.size:
            new = array.copy()
            new.flat[rng.randrange(array.size)] = rng.choice([0, 1, -1, 7, 1e6])
        elif kind == "nan" and array.size and array.dtype.kind == "f":
            new = array.copy()
            new.flat[rng.randrange(array.size)] = np.nan
        elif kind == "shape" and array.size > 1:
            new = array.reshape(-1)[:-1]
        elif kind == "dtype":
            new = array.astype(rng.choice([np.float32, np.int32, np.int64, np.float64, np.bool_]))
        elif kind == "huge":
            new = np.zeros(rng.choice([1, 1000, 100_000]), dtype=array.dtype if array.dtype.kind in "biuf" else np.float64)
        else:
            new = array[:0]
    members[name] = npy_bytes(new)
    return rebuild_npz(members), what


# ------------------------------------------------------------------------------- the files
@pytest.fixture(scope="module")
def run(tmp_path_factory):
    root = tmp_path_factory.mktemp("fuzz")
    assert main(["run", *ARGS, f"results_dir={root}"]) == 0
    (spec,) = validate_overrides([*ARGS, "generations=6", f"results_dir={root}"])
    evaluator = make_evaluator(spec.evaluator_key, spec.env_max_steps)
    return root, spec, evaluator


def fuzz(original: bytes, target: Path, read, accepted_ok, refused: tuple, rng: random.Random, forge=None, count: int = MUTATIONS) -> dict:
    """Apply ``count`` mutations (half forgeries if ``forge``) and check each outcome; returns the tallies."""
    tally = {"refused": 0, "identical": 0, "valid": 0}
    for k in range(count):
        if forge is not None and k % 2:
            data, what = forge(original, rng)
        else:
            data, what = mutate_bytes(original, rng)
        target.write_bytes(data)
        try:
            with deadline(10):
                result = read(target)
        except refused:
            tally["refused"] += 1
            continue
        except Hang:
            pytest.fail(f"mutation {k} ({what}) hangs the reader")
        except Exception as err:  # a traceback a user would see
            pytest.fail(f"mutation {k} ({what}): {type(err).__name__}: {err}")
        verdict = accepted_ok(result)
        assert verdict in ("identical", "valid"), f"mutation {k} ({what}) accepted with changed content"
        tally[verdict] += 1
    target.write_bytes(original)
    print(tally)
    return tally


# ------------------------------------------------------------------------------- checkpoints
@pytest.mark.slow
def test_fuzz_checkpoint_reader(run):
    root, spec, evaluator = run
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / ".checkpoints" / "seed_0.npz"
    original = path.read_bytes()
    identity = resume_identity(spec.identity())
    dim = evaluator.num_params

    def fresh():
        return new_seed_state(loop_settings(spec, evaluator), 0)

    def encoded(st):
        arrays = {}
        tree = _encode(st, "", arrays)
        return _canonical(tree), {k: (v.dtype.str, v.shape, v.tobytes()) for k, v in arrays.items()}

    def read(target):
        st = read_checkpoint(target, fresh(), identity=identity, seed=0, max_bytes=checkpoint_byte_limit(spec, dim))
        validate_seed_state(st, spec, dim, evaluator.max_steps)
        return st

    want = encoded(read(path))

    def accepted_ok(st):
        if encoded(st) == want:
            return "identical"
        return "valid" if plausible_cartpole_state(st, dim) else "changed"

    def forge(data, rng):
        forged, what = forge_npz(data, rng, "header.npy", True)
        if rng.random() < 0.5:  # the forger also recomputes the checksum: only validation can refuse it now
            forged, what = recompute_checksum(forged), what + " (checksum recomputed)"
        return forged, what

    tally = fuzz(original, path, read, accepted_ok, (CheckpointError,), random.Random(20261124), forge)
    assert tally["refused"] > 0.8 * MUTATIONS


def recompute_checksum(data: bytes) -> bytes:
    """The checkpoint ``data`` with its checksum made to match its (forged) content, if its header still parses."""
    from imix_cli.running.files.checkpoints import _checksum

    members = npz_members(data)
    arrays = {name[:-4]: np.load(io.BytesIO(raw), allow_pickle=False) for name, raw in members.items()}
    try:
        header = json.loads(arrays.pop("header").tobytes())
        header.pop("checksum")
        header["checksum"] = _checksum(header, arrays)
    except Exception:  # the forged header is not JSON any more: nothing to recompute
        return data
    members["header.npy"] = npy_bytes(np.frombuffer(_canonical(header).encode(), dtype=np.uint8))
    return rebuild_npz(members)


def plausible_cartpole_state(st, dim: int) -> bool:
    """An independent check (not imix's validator) that an accepted state is one this CartPole run
    (popsize 6, EIM over 3 generations, 200-step episodes) could hold."""

    def score(v):
        return isinstance(v, float) and (np.isnan(v) or 0.0 <= v <= 200.0)

    evaluations = 0
    for i, row in enumerate(st.rows):
        counts = [row[c] for c in ("evaluations", "env_steps", "reused", "reused_im", "reused_eim", "reevaluated", "popsize", "nonfinite")]
        if not all(type(c) is int and c >= 0 for c in counts) or row["generation"] != i or row["popsize"] != 6:
            return False
        if row["evaluations"] - evaluations != 6 - row["reused"] + row["reevaluated"] or not (score(row["mean_score"]) and score(row["best_score"])):
            return False
        evaluations = row["evaluations"]
    best = st.best_params
    if not (isinstance(best, np.ndarray) and best.shape == (dim,) and np.all(np.isfinite(best)) and 0.0 <= st.best_return <= 200.0):
        return False
    if type(st.evaluations) is not int or st.evaluations != evaluations or not np.all(np.isfinite(st.es.distribution.mean)):
        return False
    for g, returns in zip(st.archive.generations, st.archive.returns, strict=True):
        if g.samples.shape != (6, dim) or not np.all(np.isfinite(g.samples)) or np.any(returns < 0) or np.any(returns > 200):
            return False
        if np.any(g.source < 0) or np.any(g.source > 3) or np.any(g.index >= 6):
            return False
    return len(st.archive.generations) <= 3


# ------------------------------------------------------------------------------- policy files
def test_fuzz_policy_reader(run):
    root, _, _ = run
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / "policy_0_best.npz"
    original = path.read_bytes()
    want = read_policy(path)

    def accepted_ok(policy):
        if np.array_equal(policy.params, want.params) and json.dumps(policy.header) == json.dumps(want.header):
            return "identical"
        # a forgery without a checksum to catch it: acceptable only if it is a valid policy (checked here
        # independently of imix's validate_header)
        h = policy.header
        ints = all(type(h[k]) is int for k in ("obs_dim", "out_dim", "max_steps", "seed", "generation", "action_start"))
        ok = (
            ints and h["obs_dim"] >= 1 and h["out_dim"] >= 1 and 1 <= h["max_steps"] <= 10**7 and h["seed"] >= 0 and h["generation"] >= 0
            and isinstance(h["hidden"], list) and all(type(x) is int and 1 <= x <= 65536 for x in h["hidden"])
            and type(h["discrete"]) is bool and h["which"] in ("mean", "best") and isinstance(h["env_id"], str) and isinstance(h["env_name"], str)
            and (h["train_return"] is None or (type(h["train_return"]) in (int, float) and np.isfinite(h["train_return"])))
            and policy.params.dtype == np.float64 and policy.params.shape == (num_params_of(h),) and np.all(np.isfinite(policy.params))
        )  # fmt: skip
        return "valid" if ok else "changed"

    fuzz(original, path, read_policy, accepted_ok, (PolicyFileError,), random.Random(7), lambda d, r: forge_npz(d, r, "header.npy", False))


# ------------------------------------------------------------------------------- seed CSVs
#: Hostile cells: a quoted newline with text after it, quotes, an interpolation, a path, a formula, unicode, NUL, a long value.
HOSTILE_CELLS = ['"cem\n<any text>"', '"', "'", "${oc.env:HOME}", "../../etc/passwd", "=HYPERLINK(1)", "é漢字🙂", "\x00", "a\x00b", "x" * 5000]


@pytest.mark.slow
def test_fuzz_seed_csv_reader(run):
    root, _, _ = run
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / "seed_0.csv"
    original = path.read_bytes()
    want = read_run_csv(path)

    def accepted_ok(frame):
        if frame.equals(want):
            return "identical"
        # no checksum: a different CSV is accepted only if it keeps the contract's invariants
        assert list(frame.columns) == list(COLUMNS)
        assert np.array_equal(frame["generation"].to_numpy(), np.arange(len(frame)))
        assert (frame["seed"] == 0).all() and frame["algo"].nunique() == frame["env"].nunique() == frame["mixing"].nunique() == 1
        for column in ("evaluations", "env_steps", "mean_policy_episodes"):
            assert np.all(np.diff(frame[column].to_numpy(dtype=float)) >= 0)
        for column in INT_COLUMNS:
            values = frame[column].to_numpy(dtype=float)
            assert np.all(values >= 0) and np.all(values == np.round(values)), column
        assert np.all(frame["reused"] <= frame["popsize"]) and frame["popsize"].nunique() == 1
        assert np.all(np.isfinite(frame["sigma_mean"].to_numpy(dtype=float))) and np.all(np.isfinite(frame["wall_time"].to_numpy(dtype=float)))
        return "valid"

    def forge(data, rng):
        """A cell of the CSV replaced by another token: what a hand edit or another tool could leave."""
        lines = data.decode().split("\n")
        row = rng.randrange(1, len(lines) - 1)
        cells = lines[row].split(",")
        col = rng.randrange(len(cells))
        cells[col] = rng.choice(["-1", "1.5", "nan", "inf", "x", "", "1e400", "0", "999999", "-0.0", "1e18", "True", *HOSTILE_CELLS])
        lines[row] = ",".join(cells)
        return "\n".join(lines).encode(), f"row {row} column {col} -> {cells[col]!r}"

    tally = fuzz(original, path, read_run_csv, accepted_ok, (CorruptResultError,), random.Random(11), forge)
    assert tally["refused"] > 0.3 * MUTATIONS


SCORE_CELLS = ["1e308", "-1e308", "inf", "-inf", "+inf", "nan", "NaN", "", "1e400", "-1e400", "201", "200", "200.0000001", "-1", "-0.0", "0", "150.5",
               "1e-320", "x", "True", "0x10", "1_000", "'5'"]  # fmt: skip
SCORE_COLUMNS = ("mean_score", "best_score", "mean_policy_score")


@pytest.mark.slow
def test_fuzz_seed_csv_values(run):
    """1,000 CSVs with score cells of values that cannot be (±inf, NaN, 1e308, 201 on CartPole, words; one to three cells
    of the score columns), 1,000 accidents besides, through what every reader runs (``read_run_csv``, then
    ``check_seed_csv`` against the run's config.yaml): refused in one line, or every score a CartPole return -- finite
    in [0, 200] or NaN (the population's exactly where every member's return was non-finite), the mean at most the best."""
    import yaml

    from imix_cli.running.seed_checks import check_seed_csv

    root, _, _ = run
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / "seed_0.csv"
    original = path.read_bytes()
    config = yaml.safe_load((run_dir / "config.yaml").read_text())
    want = read_run_csv(path)

    def read(target):
        frame = read_run_csv(target)
        check_seed_csv(frame, target, config)
        return frame

    def accepted_ok(frame):
        if frame.equals(want):
            return "identical"
        mean, best, theta = (frame[c].to_numpy(dtype=float) for c in SCORE_COLUMNS)
        none_finite = frame["nonfinite"].to_numpy() == frame["popsize"].to_numpy()
        assert np.array_equal(np.isnan(mean), none_finite) and np.array_equal(np.isnan(best), none_finite)
        for values in (mean, best, theta):
            measured = values[~np.isnan(values)]
            assert np.all((measured >= 0) & (measured <= 200)), values
        assert np.all(mean[~none_finite] <= best[~none_finite] + 1e-9 * np.maximum(1, np.abs(best[~none_finite])))
        return "valid"

    def forge(data, rng):
        lines = data.decode().split("\n")
        header = lines[0].split(",")
        what = []
        for _ in range(rng.randint(1, 3)):
            row = rng.randrange(1, len(lines) - 1)
            cells = lines[row].split(",")
            column = rng.choice(SCORE_COLUMNS)
            cells[header.index(column)] = rng.choice(SCORE_CELLS)
            lines[row] = ",".join(cells)
            what.append(f"row {row} {column} -> {cells[header.index(column)]!r}")
        return "\n".join(lines).encode(), "; ".join(what)

    tally = fuzz(original, path, read, accepted_ok, (CorruptResultError,), random.Random(47), forge, count=2 * MUTATIONS)
    assert tally["refused"] > 0.5 * MUTATIONS


# ------------------------------------------------------------------------------- config.yaml
@pytest.mark.slow
def test_fuzz_config_yaml_reader(run, tmp_path):
    """``imix run`` reads config.yaml back to compare configs: a mutated one is refused, or the run goes
    on only if its identity is unchanged."""
    root, spec, _ = run
    (run_dir,) = (root / "default").iterdir()
    path = run_dir / "config.yaml"
    original = path.read_bytes()
    import yaml

    want = resume_identity(spec.identity())

    def read(target):
        text = target.read_bytes()  # what prepare_run_dir reads (it may rewrite the file when the run goes on)
        prepare_run_dir(spec)
        return yaml.safe_load(text)

    def accepted_ok(config):
        from imix_cli.running.config.run_spec import identity_of

        # imix compares identities key by key with None for a missing key (run_spec.differing_keys), so a
        # key whose value is null is the same as no key: compare what imix compares
        def meaningful(identity):
            return {k: v for k, v in resume_identity(identity).items() if v is not None}

        assert meaningful(identity_of(config)) == meaningful(want)
        return "identical" if target_unchanged(config) else "valid"

    def target_unchanged(config):
        return config == yaml.safe_load(original.decode())

    def forge(data, rng):
        text = data.decode()
        lines = text.splitlines()
        k = rng.randrange(len(lines))
        value = rng.choice(["&a [*a]", "*nope", "!!python/object:os.system ls", "[" * 50, "1e400", "-1", "null", "{a: 1}", "'x' * 3", "&x [a] \n b: *x"])
        key = lines[k].split(":", 1)[0]
        if rng.random() < 0.2:  # a key that is not a string
            key = rng.choice(["1", "null", "true", "3.5", "? [a, b]\n"])
        lines[k] = f"{key}: {value}"
        return "\n".join(lines).encode(), f"line {k} -> {value}"

    fuzz(original, path, read, accepted_ok, (RunError,), random.Random(3), forge)
    prepare_run_dir(spec)  # the original is accepted again


# ------------------------------------------------------------------------------- through the CLI
def test_mutated_files_through_the_cli_never_give_a_traceback(run, tmp_path, capfd):
    """A few mutations through the commands themselves: ``imix eval`` on policy files, ``imix plot`` on CSVs."""
    root, _, _ = run
    (run_dir,) = (root / "default").iterdir()
    rng = random.Random(5)
    policy = run_dir / "policy_0_mean.npz"
    csv = run_dir / "seed_0.csv"
    originals = {policy: policy.read_bytes(), csv: csv.read_bytes()}
    try:
        for k in range(12):
            target = policy if k % 2 == 0 else csv
            data, what = mutate_bytes(originals[target], rng) if k % 4 < 2 else forge_npz(originals[policy], rng, "header.npy", False)
            if k % 4 >= 2:
                target = policy
            target.write_bytes(data)
            capfd.readouterr()
            command = ["eval", f"results_dir={root}", "episodes=2"] if target == policy else ["plot", f"results_dir={root}", "only=reuse,threshold"]
            with deadline(60):
                status = main(command)
            out, err = capfd.readouterr()
            assert "Traceback" not in out + err, f"{command[0]} after {what}: {err}"
            assert status in (0, 1), f"{command[0]} after {what}: status {status}"
            target.write_bytes(originals[target])
    finally:
        for path, data in originals.items():
            path.write_bytes(data)
    assert pd.read_csv(csv).shape[0] == 4


# ------------------------------------------------------------------------------- the command line
#: Values no key takes, the kinds a hostile or careless command line holds: newlines, quotes, interpolations (Hydra's and
#: OmegaConf's resolvers), paths out of the folder, a very long value, unicode, NUL, control characters, sweep syntax.
HOSTILE = [
    "a\nb", "a\rb", "'", '"', "'x'", '"x"', "'a\nb'", "\\", "${oc.env:HOME}", "${hydra:runtime.cwd}", "${now:%Y}", "${undefined_key}",
    "${seeds}", "${oc.decode:'[1]'}", "${", "}", "$", "../..", "../../etc/passwd", "/", "x" * 5000, "é漢字🙂", "\u202e", "a\x00b", "\x00",
    "\t", " x ", "a,b", "range(1,4)", "choice(a,b)", "glob(*)", "interval(0,1)", "tag(x,y)", "shuffle(1,2)", "[", "{a:", "=",
    "nonexistent_module_q:Foo-v0", "???", "null", "", " ", "\x7f", "1e400", "-1e400", "nan", "-inf", "0x10", "1_000",
]  # fmt: skip
TYPED = ["0", "1", "2", "-1", "3", "50", "2.5", "0.5", "1e-300", "1e300", "true", "false", "[]", "[1,2]", "[a]", "{a: 1}", "123456789012345678901"]
EXTRA_KEYS = ["algo", "env", "hydra.job.chdir", "hydra.run.dir", "hydra.sweep.dir", "hydra/launcher", "hydra.callbacks.x._target_", "hydra.verbose"]


def random_command_line(rng: random.Random, keys: tuple, root: Path) -> list:
    """One ``imix run`` command line: 1-5 overrides of keys of the table (or mistyped, or unknown, or Hydra's), each with a
    typed, a valid-choice or a hostile value, some with ``+``/``++``/``~``, sometimes ``-m`` and Hydra's flags."""
    from imix_cli.core.registry import ALGO_NAMES

    choices = [*ALGO_NAMES, "cartpole", "acrobot", "gym", "exact", "paper", "sun2009", "csa", "cemrl", "local", "pool", "ray", "tensorboard"]
    args = [f"results_dir={root}", "seeds=1", "workers=1"]
    careful = rng.random() < 0.4  # keys of the table with typed or valid values only: many lines are accepted
    for _ in range(1 if careful else rng.randint(1, 5)):
        key = rng.choice(keys if careful else keys + tuple(EXTRA_KEYS))
        if not careful and rng.random() < 0.15:  # a typo of a real key
            k = rng.randrange(len(key))
            key = key[:k] + rng.choice("abcdefghijklmnopqrstuvwxyz._") + key[k + 1 :]
        value = rng.choice([rng.choice(TYPED), rng.choice(choices)] + ([] if careful else [rng.choice(HOSTILE), rng.choice(HOSTILE) + rng.choice(TYPED)]))
        if rng.random() < 0.2:  # Hydra's quoting: the hostile text reaches the config as a string
            value = "'" + value.replace("\\", "\\\\").replace("'", "\\'") + "'"
        prefix = "" if careful else rng.choice(["", "", "", "", "+", "++", "~"])
        args.append(f"{prefix}{key}" if prefix == "~" and rng.random() < 0.5 else f"{prefix}{key}={value}")
    if rng.random() < 0.3:
        args.insert(0, "-m")
    if rng.random() < 0.1:
        args += rng.choice([["--config-name", rng.choice(HOSTILE)], [f"--config-dir={rng.choice(HOSTILE)}"], ["--config-dir"], ["-cn"], ["--seeds", "3"],
                            ["-x"], ["--config-path", rng.choice(HOSTILE)]])  # fmt: skip
    return args


@pytest.mark.slow
def test_fuzz_the_command_line_validation(tmp_path, monkeypatch):
    """1,000 random ``imix run`` command lines through its validation alone (``validate_run_args``: in-process, no episode):
    each is accepted or refused with one line (ConfigError, exit 2; RunError, exit 1) -- never another exception, never a
    hang -- and nothing is written, wherever its results_dir, experiment or Hydra folders point."""
    from imix_cli.commands.cli import validate_run_args
    from imix_cli.running.config.compose import ConfigError, all_keys

    monkeypatch.chdir(tmp_path)
    root = tmp_path / "results"
    rng, keys = random.Random(20261127), all_keys()
    tally = {"accepted": 0, "refused": 0}
    for k in range(MUTATIONS):
        args = random_command_line(rng, keys, root)
        try:
            with deadline(30):
                validate_run_args(args)
            tally["accepted"] += 1
        except (ConfigError, RunError) as err:
            message = str(err)
            assert message.strip() and "\n" not in message and "Traceback" not in message, f"case {k} {args!r}: {message!r}"
            tally["refused"] += 1
        except Hang:
            pytest.fail(f"case {k}: validation of {args!r} hangs")
        except Exception as err:  # a traceback a user would see
            pytest.fail(f"case {k}: {args!r}: {type(err).__name__}: {err}")
    print(tally)
    assert list(tmp_path.iterdir()) == []  # validation wrote nothing, not even results_dir
    assert tally["accepted"] > 0.02 * MUTATIONS and tally["refused"] > 0.5 * MUTATIONS

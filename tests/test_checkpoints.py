"""Checkpoints are data that cannot lie or run code (imix_cli.running.files.checkpoints).

A checkpoint read back is either exactly what was saved, or refused with one warning line
naming the file -- whatever happened to the file: truncation, random bit flips, another seed's
or another config's checkpoint copied over it, another format version, or a pickle payload
(which must never execute). The end-to-end cases check the CSV itself: a damaged checkpoint
costs recomputation, never a wrong result.
"""

import io
import json
import pickle
import random
import zipfile
from pathlib import Path

import numpy as np
import pandas as pd
import pytest

from imix_cli.commands.cli import main
from imix_cli.core.evaluation import make_evaluator
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.files import checkpoints
from imix_cli.running.files.checkpoints import checkpoint_path, save_checkpoint
from imix_cli.running.loop.lockstep import advance_lockstep, loop_settings, new_seed_state
from imix_cli.running.loop.resume import load_checkpoint
from imix_cli.running.run_folder import prepare_run_dir
from imix_cli.running.runner import run_seeds

COMMON = ["algo=snes", "env=cartpole", "eim=true", "seeds=2", "generations=12", "popsize=8", "checkpoint_every=4", "checkpoint_seconds=0",
          "workers=1", "progress=false"]  # fmt: skip


def spec_and_states(tmp_path, overrides=(), generations=5):
    """A prepared run folder and its two seeds advanced ``generations`` generations (archive full)."""
    (spec,) = validate_overrides([*COMMON, *overrides, f"results_dir={tmp_path}"])
    prepare_run_dir(spec)
    evaluator = make_evaluator(spec.evaluator_key, spec.env_max_steps)
    settings = loop_settings(spec, evaluator)
    states = [new_seed_state(settings, seed) for seed in (0, 1)]
    for _ in range(generations):
        advance_lockstep(states, settings, evaluator)
    return spec, states, evaluator


def encoded(st) -> tuple[str, dict]:
    """The state's content as canonical JSON + its arrays: equal content <=> equal encodings."""
    arrays = {}
    tree = checkpoints._encode(st, "", arrays)
    return checkpoints._canonical(tree), {k: (v.dtype.str, v.shape, v.tobytes()) for k, v in arrays.items()}


def fresh(spec, evaluator, seed=0):
    return new_seed_state(loop_settings(spec, evaluator), seed)


def load(spec, evaluator, seed=0):
    """load_checkpoint's result and the warning lines it gave."""
    warnings = []
    st = load_checkpoint(spec.run_dir, seed, spec.identity(), fresh(spec, evaluator, seed), warn=warnings.append)
    return st, warnings


def test_round_trip_restores_everything_and_continues_bit_identically(tmp_path):
    spec, states, evaluator = spec_and_states(tmp_path)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    loaded, warnings = load(spec, evaluator)
    assert warnings == []
    assert len(loaded.archive.generations) == spec.eim_generations and loaded.generation == 5
    assert encoded(loaded) == encoded(states[0])
    # Continuing both: the next generations (rows, ES, RNG states) are identical.
    other = fresh(spec, evaluator, 1)
    for _ in range(4):
        advance_lockstep([states[0], other], loop_settings(spec, evaluator), evaluator)
    for _ in range(4):
        advance_lockstep([loaded], loop_settings(spec, evaluator), evaluator)
    assert encoded(loaded) == encoded(states[0])


def test_truncation_at_random_offsets_is_refused_with_one_warning(tmp_path):
    spec, states, evaluator = spec_and_states(tmp_path)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    path = checkpoint_path(spec.run_dir, 0)
    data = path.read_bytes()
    rng = random.Random(1)
    for cut in [0, 1, len(data) - 1, *rng.sample(range(2, len(data) - 1), 60)]:
        path.write_bytes(data[:cut])
        st, warnings = load(spec, evaluator)
        assert st is None and len(warnings) == 1 and str(path) in warnings[0] and "restarts from scratch" in warnings[0], (cut, warnings)


def test_random_bit_flips_never_load_changed_content(tmp_path):
    """300 single-bit flips at random positions: each is refused, or loads exactly the saved state."""
    spec, states, evaluator = spec_and_states(tmp_path)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    path = checkpoint_path(spec.run_dir, 0)
    data, expected = path.read_bytes(), encoded(states[0])
    rng = random.Random(2)
    outcome = {"refused": 0, "identical": 0}
    for _ in range(300):
        flipped = bytearray(data)
        bit = rng.randrange(len(data) * 8)
        flipped[bit // 8] ^= 1 << (bit % 8)
        path.write_bytes(bytes(flipped))
        st, warnings = load(spec, evaluator)
        if st is None:
            assert len(warnings) == 1 and str(path) in warnings[0], warnings
            outcome["refused"] += 1
        else:
            assert warnings == [] and encoded(st) == expected, f"bit {bit} loaded changed content"
            outcome["identical"] += 1
    # Most bytes are array data or header JSON: almost every flip must be caught.
    assert outcome["refused"] >= 250, outcome


def test_flips_inside_the_stored_arrays_and_header_are_caught_by_the_checksum(tmp_path):
    """Rewrite the .npz with one changed number (zip CRCs then valid): only the checksum can tell."""
    spec, states, evaluator = spec_and_states(tmp_path)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    path = checkpoint_path(spec.run_dir, 0)
    with np.load(path, allow_pickle=False) as npz:
        members = {k: npz[k] for k in npz.files}
    members["es/mean"] = members["es/mean"] + 1e-3  # the reproduction: the ES mean moved
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    path.write_bytes(buffer.getvalue())
    st, warnings = load(spec, evaluator)
    assert st is None and "checksum" in warnings[0]


def rewrite_header(path: Path, change) -> None:
    """Apply ``change`` to the header and re-sign it (a well-formed checkpoint that must still be refused)."""
    with np.load(path, allow_pickle=False) as npz:
        members = {k: npz[k] for k in npz.files}
    header = json.loads(members.pop("header").tobytes())
    header.pop("checksum")
    change(header)
    header["checksum"] = checkpoints._checksum(header, members)
    buffer = io.BytesIO()
    np.savez(buffer, header=np.frombuffer(checkpoints._canonical(header).encode(), np.uint8), **members)
    path.write_bytes(buffer.getvalue())


@pytest.mark.parametrize(
    "change, reason",
    [
        (lambda h: h.update(version=1), "format version 1"),
        (lambda h: h.update(imix_version="0.0.1"), "imix 0.0.1"),
        (lambda h: h.update(seed=1), "holds seed 1"),
        (lambda h: h.update(config_hash="0" * 64), "another config"),
        (lambda h: h.update(format="something-else"), "not an imix checkpoint"),
        (lambda h: h["state"]["state"].pop("rows"), "does not fit"),
    ],
    ids=["format version", "imix version", "seed", "config", "format", "missing field"],
)
def test_a_well_formed_checkpoint_of_another_kind_is_refused(tmp_path, change, reason):
    spec, states, evaluator = spec_and_states(tmp_path, generations=2)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    rewrite_header(checkpoint_path(spec.run_dir, 0), change)
    st, warnings = load(spec, evaluator)
    assert st is None and len(warnings) == 1 and reason in warnings[0], warnings


def test_a_swapped_seed_is_refused(tmp_path):
    spec, states, evaluator = spec_and_states(tmp_path, generations=2)
    save_checkpoint(spec.run_dir, states[1], spec.identity())
    checkpoint_path(spec.run_dir, 1).rename(checkpoint_path(spec.run_dir, 0))  # seed 1's file at seed 0's name
    st, warnings = load(spec, evaluator)
    assert st is None and "holds seed 1, not seed 0" in warnings[0]


def test_a_foreign_config_is_refused(tmp_path):
    spec, states, evaluator = spec_and_states(tmp_path, generations=2)
    (other,) = validate_overrides([*COMMON, "weight_decay=0.1", f"results_dir={tmp_path}"])
    save_checkpoint(spec.run_dir, states[0], other.identity())
    st, warnings = load(spec, evaluator)
    assert st is None and "another config" in warnings[0]


class Payload:
    """Unpickling this creates ``marker``: proof that code ran."""

    def __init__(self, marker):
        self.marker = str(marker)

    def __reduce__(self):
        return (Path.touch, (Path(self.marker),))


def test_a_pickle_payload_is_never_executed(tmp_path, capfd):
    """The payload sits at the checkpoint's name and inside an .npz object array; the run completes from
    scratch and the marker never appears."""
    marker = tmp_path / "PWNED"
    payload = pickle.dumps(Payload(marker))
    pickle.loads(payload)  # the payload works: it does create the marker when unpickled
    assert marker.exists()
    marker.unlink()
    (spec,) = validate_overrides([*COMMON, f"results_dir={tmp_path / 'r'}"])
    todo = prepare_run_dir(spec)
    checkpoint_path(spec.run_dir, 0).parent.mkdir()
    checkpoint_path(spec.run_dir, 0).write_bytes(payload)
    buffer = io.BytesIO()
    np.savez(buffer, header=np.zeros(3, np.uint8), evil=np.array([Payload(marker)], dtype=object))
    checkpoint_path(spec.run_dir, 1).write_bytes(buffer.getvalue())
    capfd.readouterr()
    run_seeds(spec, todo, progress=lambda n: None)
    err = capfd.readouterr().err
    assert not marker.exists()
    assert err.count("checkpoint ignored") == 2, err
    assert len(pd.read_csv(spec.run_dir / "seed_0.csv")) == 12


def test_a_damaged_checkpoint_gives_the_uninterrupted_csv_not_a_wrong_one(tmp_path, capfd, monkeypatch):
    """End to end: a checkpoint whose ES mean moved by 1e-3 (re-zipped, CRCs valid) is refused and the
    seed's CSV equals that of an uninterrupted run. The Python loop (one progress call per generation,
    so the interruption falls mid-run; the compiled loop gives the same rows: test_compiled_loop.py)."""
    monkeypatch.setenv("IMIX_COMPILED_LOOP", "0")
    assert main(["run", *COMMON, f"results_dir={tmp_path / 'ref'}"]) == 0
    (spec,) = validate_overrides([*COMMON, f"results_dir={tmp_path / 'run'}"])
    todo = prepare_run_dir(spec)
    calls = {"n": 0}

    def stop_after_nine(n):
        calls["n"] += 1
        if calls["n"] == 9:
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        run_seeds(spec, todo, progress=stop_after_nine)
    path = checkpoint_path(spec.run_dir, 0)
    with np.load(path, allow_pickle=False) as npz:
        members = {k: npz[k] for k in npz.files}
    members["es/mean"] = members["es/mean"] + 1e-3
    buffer = io.BytesIO()
    np.savez(buffer, **members)
    path.write_bytes(buffer.getvalue())
    capfd.readouterr()
    assert main(["run", *COMMON, f"results_dir={tmp_path / 'run'}"]) == 0
    err = capfd.readouterr().err
    assert (
        "seed 0 restarts from scratch" in err
        and "resuming seed 1 of" in err
        and "at generation 8 from its checkpoint" in err
        and "imix: seed 0 of" in err
        and "starts from generation 0" in err
    ), err
    for seed in (0, 1):
        ref = pd.read_csv(next((tmp_path / "ref").rglob(f"seed_{seed}.csv"))).drop(columns="wall_time")
        got = pd.read_csv(spec.run_dir / f"seed_{seed}.csv").drop(columns="wall_time")
        pd.testing.assert_frame_equal(got, ref)


def test_checkpoint_is_a_plain_zip_of_npy_files(tmp_path):
    spec, states, evaluator = spec_and_states(tmp_path, generations=2)
    save_checkpoint(spec.run_dir, states[0], spec.identity())
    with zipfile.ZipFile(checkpoint_path(spec.run_dir, 0)) as z:
        names = z.namelist()
    assert "header.npy" in names and "es/mean.npy" in names and "archive/generations/0/samples.npy" in names
    assert not list(spec.run_dir.rglob("*.tmp"))


def test_archived_generations_are_saved_field_by_field_whatever_their_fields(tmp_path, monkeypatch):
    """A Generation with one more array field (as the lead is adding) round-trips without any change
    to imix_cli.running.files.checkpoints: fields are found with dataclasses.fields, not listed."""
    import dataclasses

    import imix_cli.core.mixing as mixing

    Extended = dataclasses.make_dataclass("Generation", [("weights", np.ndarray, dataclasses.field(default=None))], bases=(mixing.Generation,))
    monkeypatch.setattr(checkpoints, "Generation", Extended)
    spec, states, evaluator = spec_and_states(tmp_path, generations=3)
    st = states[0]
    st.archive.generations = [
        Extended(**{f.name: getattr(g, f.name) for f in dataclasses.fields(g)}, weights=np.arange(3.0) + k) for k, g in enumerate(st.archive.generations)
    ]
    save_checkpoint(spec.run_dir, st, spec.identity())
    loaded, warnings = load(spec, evaluator)
    assert warnings == [] and [type(g) for g in loaded.archive.generations] == [Extended] * 3
    for k, g in enumerate(loaded.archive.generations):
        np.testing.assert_array_equal(g.weights, np.arange(3.0) + k)
    assert encoded(loaded) == encoded(st)


def test_the_rows_encoding_kept_between_checkpoints_gives_the_encoding_of_all_rows(tmp_path):
    """A seed's rows are encoded once and only their new rows after (``tables``): every checkpoint
    must still hold what encoding all its rows gives, whatever happened to the rows in between."""
    spec, (st, _), evaluator = spec_and_states(tmp_path, generations=3)
    tables = {}

    def same_as_whole(label):
        arrays = {}
        tree = checkpoints._encode(st, "", arrays, tables)
        assert (checkpoints._canonical(tree), {k: (v.dtype.str, v.shape, v.tobytes()) for k, v in arrays.items()}) == encoded(st), label

    same_as_whole("first")
    for _ in range(2):
        advance_lockstep([st], loop_settings(spec, evaluator), evaluator)
    same_as_whole("rows added")
    same_as_whole("no row added")
    st.rows[1]["mean_score"] += 1.0
    same_as_whole("an earlier row changed in place")
    st.rows[0] = dict(st.rows[0], seed=7)
    same_as_whole("an earlier row replaced")
    st.rows = [dict(r) for r in st.rows[:3]]
    same_as_whole("the rows replaced by fewer (a resumed seed's)")
    st.rows[2]["wall_time"], st.rows[2]["sigma_mean"] = st.rows[2]["sigma_mean"], st.rows[2]["wall_time"]
    same_as_whole("two values of a row swapped")
    row = st.rows[1]
    st.rows[1] = {k: row[k] for k in reversed(row)}
    same_as_whole("an earlier row's keys reordered")
    st.rows[1] = row
    same_as_whole("and back")
    assert "rows" in tables  # the rows' encoding is kept ...
    st.rows.append(dict(st.rows[-1], generation=3, reused=1.5))
    same_as_whole("a new row changes a column's kind (int to float)")
    st.rows.append(dict(st.rows[-1], generation=4, reused=2))
    same_as_whole("a column of mixed kinds")
    assert "rows" not in tables  # ... but for a column of mixed kinds


@pytest.mark.parametrize("seconds, periodic", [(0, 2), (3600, 0)])
def test_a_periodic_checkpoint_waits_for_checkpoint_seconds_and_the_final_state_does_not(tmp_path, monkeypatch, seconds, periodic):
    """checkpoint_every=4 over 12 generations falls due at generations 4 and 8 (and the final state at 12);
    with checkpoint_seconds=3600 the periodic ones are skipped (the run takes a second), the final one is not.
    The final state is written durably (fsync), the periodic ones are not (a kill leaves them whole anyway)."""
    from imix_cli.running.files import run_writer

    saved = []
    real = run_writer.save_checkpoint

    def recording(run_dir, st, *args, durable=True, **kwargs):
        saved.append((st.seed, st.generation, durable))
        real(run_dir, st, *args, durable=durable, **kwargs)

    monkeypatch.setattr(run_writer, "save_checkpoint", recording)
    (spec,) = validate_overrides([*COMMON, f"checkpoint_seconds={seconds}", f"results_dir={tmp_path}"])
    prepare_run_dir(spec)
    run_seeds(spec, [0, 1])
    for seed in (0, 1):
        mine = [(g, durable) for s, g, durable in saved if s == seed]
        assert mine == [(4, False), (8, False)][:periodic] + [(12, True)], mine
        assert checkpoint_path(spec.run_dir, seed).exists()  # the final state, from which more generations continue

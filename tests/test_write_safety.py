"""Every file a command writes goes through the one writer (imix_cli.running.files.writing).

Each test plants what a received results folder could hold -- a symbolic link at a file a command writes,
or at a folder above it, a CSV cell with a newline or a formula -- or cuts a write short (a full disk, a
kill -9 in the middle of a PDF), and checks: one line naming the link, a non-zero exit, the link's
target untouched, and no truncated file where a good one was.
"""

from __future__ import annotations

import csv
import os
import shutil
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from imix_cli.commands.cli import main

RUN = "cem-cartpole-none-popsize=6"
TINY = ["algo=cem", "env=cartpole", "seeds=2", "generations=2", "popsize=6", "progress=false", "workers=1"]
VICTIM_TEXT = "the user's own file\n"


@pytest.fixture(scope="module")
def trained(tmp_path_factory):
    """A finished experiment ``e`` (2 seeds, policy files) with its figures drawn once."""
    root = tmp_path_factory.mktemp("results")
    assert main(["run", *TINY, f"results_dir={root}", "experiment=e"]) == 0
    assert main(["plot", f"results_dir={root}", "experiment=e"]) == 0
    return root


@pytest.fixture
def results(trained, tmp_path):
    """A fresh copy of the trained results folder, to be damaged by one test; and a victim file outside it."""
    shutil.copytree(trained, tmp_path / "r", symlinks=True)
    (tmp_path / "victim").write_text(VICTIM_TEXT)
    return tmp_path / "r"


def plant(link: Path, target: Path) -> None:
    """Replace ``link`` (a file or folder, or nothing) by a symbolic link to ``target``."""
    if link.is_dir() and not link.is_symlink():
        shutil.rmtree(link)
    elif link.exists() or link.is_symlink():
        link.unlink()
    link.symlink_to(target, target_is_directory=target.is_dir())


def snapshot(folder: Path) -> dict:
    """Every file under ``folder`` (links not followed) -> its bytes."""
    return {p.relative_to(folder): p.read_bytes() for p in sorted(folder.rglob("*")) if p.is_file() and not p.is_symlink()}


def error_line(err: str, command: str) -> str:
    """The one error line of ``imix <command>`` (warnings may come before it; a traceback never)."""
    assert "Traceback" not in err, err
    lines = [line for line in err.splitlines() if line.startswith(f"imix {command}") and "warning" not in line]
    assert len(lines) == 1, err
    return lines[0]


def copy_elsewhere(folder: Path, tmp_path: Path) -> Path:
    """A copy of ``folder`` outside the results folder: what a link planted in its place points to."""
    elsewhere = tmp_path / f"elsewhere-{folder.name}"
    shutil.copytree(folder, elsewhere, symlinks=True)
    return elsewhere


def refused(capsys, tmp_path, results, argv: list, command: str, link: Path, target: Path) -> None:
    """Plant ``link`` -> ``target``, run ``imix <argv>``: exit non-zero, one line naming the link, the target untouched."""
    plant(link, target)
    before = snapshot(target) if target.is_dir() else target.read_bytes()
    capsys.readouterr()
    assert main(argv) != 0
    line = error_line(capsys.readouterr().err, command)
    assert str(link) in line and "symbolic link" in line, line
    assert (snapshot(target) if target.is_dir() else target.read_bytes()) == before
    assert link.is_symlink()


# ------------------------------------------------------------------ item 1: imix plot (and only=)
def _plot_targets(results: Path, only: str | None) -> list:
    figures = results / "e" / "figures"
    files = sorted(p.name for p in figures.iterdir() if only is None or p.name.startswith(f"{only}."))
    assert files
    return ["e", "e/figures", *(f"e/figures/{name}" for name in files)]


@pytest.mark.parametrize("only", ["iqm", pytest.param(None, marks=pytest.mark.slow)])
def test_plot_refuses_a_link_at_every_file_it_writes_and_at_every_folder_above(results, tmp_path, capsys, only):
    """Once, plot wrote through ``figures/<file>`` links and a ``figures`` link (every table went elsewhere)."""
    argv = ["plot", f"results_dir={results}", "experiment=e", *([f"only={only}"] if only else [])]
    for rel in _plot_targets(results, only):
        link = results / rel
        if link.is_dir():
            target = copy_elsewhere(link, tmp_path)
        else:
            target = tmp_path / f"victim-{link.name}"
            target.write_text(VICTIM_TEXT)
        refused(capsys, tmp_path, results, argv, "plot", link, target)
        link.unlink()
        shutil.move(target, link) if target.is_dir() else None  # the folder back in place for the next path


def _poison_csv(results: Path, text: str) -> None:
    path = results / "e" / RUN / "seed_0.csv"
    with path.open() as fh:
        rows = list(csv.reader(fh))
    column = rows[0].index("algo")
    for row in rows[1:]:
        row[column] = text
    with path.open("w", newline="") as fh:
        csv.writer(fh).writerows(rows)
    # The attacker sends the whole folder: its config.yaml names the same algo, so the CSV agrees with its run's
    # config (imix_cli.running.seed_checks) and the cell reaches the tables, where the writer must neutralise it.
    import yaml

    config_path = results / "e" / RUN / "config.yaml"
    config = yaml.safe_load(config_path.read_text())
    config["algo"]["name"] = text
    config_path.write_text(yaml.safe_dump(config))


def test_the_issues_attack_a_newline_cell_and_a_linked_iqm_md_writes_nothing_outside(results, tmp_path, capsys):
    """The exact attack once reproduced: ``algo="cem\\n<text>"`` in a CSV and ``figures/iqm.md`` linked to a user's file
    (a shell profile, authorized_keys): the file is untouched; and without the link no cell starts a line of a table."""
    _poison_csv(results, "cem\nssh-rsa AAAA attacker")
    victim = tmp_path / "victim"
    refused(capsys, tmp_path, results, ["plot", f"results_dir={results}", "experiment=e", "only=iqm"], "plot", results / "e/figures/iqm.md", victim)
    assert victim.read_text() == VICTIM_TEXT
    (results / "e/figures/iqm.md").unlink()
    main(["plot", f"results_dir={results}", "experiment=e", "only=iqm"])
    for suffix in ("csv", "md", "tex"):
        text = (results / "e" / "figures" / f"iqm.{suffix}").read_text()
        assert "ssh-rsa" in text  # the cell is there ...
        assert not any(line.startswith("ssh-rsa") for line in text.splitlines()), text  # ... never on a line of its own


# ------------------------------------------------------------------ item 2: imix eval, imix render, imix run, imix run -m
@pytest.mark.parametrize("rel", ["e", f"e/{RUN}", f"e/{RUN}/eval.csv"])
def test_eval_refuses_a_linked_experiment_run_folder_or_eval_csv(results, tmp_path, capsys, rel):
    """Once, eval wrote eval.csv through a linked experiment or run folder."""
    link = results / rel
    target = copy_elsewhere(link, tmp_path) if link.is_dir() else tmp_path / "victim"
    refused(capsys, tmp_path, results, ["eval", f"results_dir={results}", "experiment=e", "episodes=2"], "eval", link, target)


@pytest.mark.parametrize("rel", [f"e/{RUN}", "out.gif"])
def test_render_refuses_a_linked_run_folder_or_output(results, tmp_path, capsys, rel):
    """render's default output goes into the run folder through the writer; out= is refused if it is a link."""
    pytest.importorskip("pygame")
    link = results / rel if rel != "out.gif" else tmp_path / "out.gif"
    target = copy_elsewhere(link, tmp_path) if link.is_dir() else tmp_path / "victim"
    argv = ["render", f"results_dir={results}", "experiment=e", f"run={RUN}", "frames=3", *([f"out={link}"] if rel == "out.gif" else [])]
    refused(capsys, tmp_path, results, argv, "render", link, target)


@pytest.mark.parametrize(
    "rel", ["e", f"e/{RUN}", f"e/{RUN}/config.yaml", f"e/{RUN}/seed_0.csv", f"e/{RUN}/policy_0_mean.npz", f"e/{RUN}/.checkpoints", f"e/{RUN}/.lock"]
)
def test_run_refuses_a_link_at_each_path_it_writes(results, tmp_path, capsys, rel):
    """imix run continuing the experiment (one more generation): a link at any file or folder it writes is refused."""
    link = results / rel
    if rel.endswith(".checkpoints"):
        link.mkdir(exist_ok=True)
    target = copy_elsewhere(link, tmp_path) if link.is_dir() else tmp_path / "victim"
    argv = ["run", *(a for a in TINY if not a.startswith("generations=")), "generations=3", f"results_dir={results}", "experiment=e"]
    refused(capsys, tmp_path, results, argv, "run", link, target)


def test_a_sweep_refuses_a_linked_multirun_folder(results, tmp_path, capsys):
    """Once, ``imix run -m`` wrote multirun.yaml and its job folders through a linked ``.multirun``."""
    target = tmp_path / "elsewhere"
    target.mkdir()
    argv = ["run", "-m", "algo=cem", "env=cartpole", "seeds=1", "generations=1", "popsize=4,6", "progress=false", "workers=1"]
    argv += [f"results_dir={results}", "experiment=e"]
    refused(capsys, tmp_path, results, argv, "run", results / "e" / ".multirun", target)
    assert not list(target.iterdir())


# ------------------------------------------------------------------ item 3: a write cut short never leaves a truncated file
def _run_plot(results: Path, prelude: str = "", preexec=None) -> subprocess.CompletedProcess:
    command = f"sys.exit(main(['plot', 'results_dir={results}', 'experiment=e']))"
    code = textwrap.dedent(prelude) + f"\nimport sys\nfrom imix_cli.commands.cli import main\n{command}\n"
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, preexec_fn=preexec, timeout=600)


def _no_temporaries(folder: Path) -> bool:
    return not [p for p in folder.iterdir() if p.name.endswith(".tmp")]


def test_a_full_disk_during_plot_leaves_every_good_file_as_it_was(results):
    """Once, a full disk left a 0-byte iqm.csv in place of a good one. Here each file may hold at most
    2 kB (RLIMIT_FSIZE: a write beyond it fails with EFBIG, as ENOSPC does on a full disk)."""
    import resource
    import signal

    figures = results / "e" / "figures"
    before = snapshot(figures)
    assert any(len(data) > 2048 for data in before.values()) and any(len(data) <= 2048 for data in before.values())

    def small_disk():
        signal.signal(signal.SIGXFSZ, signal.SIG_IGN)  # the write fails (EFBIG) instead of killing the process
        resource.setrlimit(resource.RLIMIT_FSIZE, (2048, 2048))

    proc = _run_plot(results, preexec=small_disk)
    assert proc.returncode == 1 and "Traceback" not in proc.stderr, proc.stderr
    assert "cannot write" in error_line(proc.stderr, "plot")
    assert snapshot(figures) == before and _no_temporaries(figures)


def test_a_kill_9_in_the_middle_of_a_pdf_leaves_the_old_pdf(results):
    """Once, kill -9 of imix plot replaced a good PDF with a truncated one. The kill lands when half of
    the first PDF's bytes are written, wherever matplotlib writes them."""
    figures = results / "e" / "figures"
    before = snapshot(figures)
    prelude = """
        import io, os, signal
        from matplotlib.figure import Figure
        real_savefig = Figure.savefig

        def savefig(self, fname, **kw):
            if kw.get("format") != "pdf" and not str(fname).endswith(".pdf"):
                return real_savefig(self, fname, **kw)
            data = io.BytesIO()
            real_savefig(self, data, **kw)
            fh = open(fname, "wb") if isinstance(fname, (str, os.PathLike)) else fname
            fh.write(data.getvalue()[: len(data.getvalue()) // 2])
            fh.flush()
            os.kill(os.getpid(), signal.SIGKILL)

        Figure.savefig = savefig
    """
    proc = _run_plot(results, prelude)
    assert proc.returncode == -9, proc.stderr
    after = {path: data for path, data in snapshot(figures).items() if not path.name.endswith(".tmp")}
    assert after == before
    assert [p.name for p in figures.iterdir() if p.name.endswith(".tmp")]  # the half-written temporary, never at a final name


# ------------------------------------------------------------------ item 9: table cells are data, not formulas or lines
def test_formula_cells_are_quoted_in_every_written_table_and_numbers_stay_numbers(results, capsys):
    """Once, ``=HYPERLINK(...)`` in a CSV was copied into figures/*.csv. A text cell starting with =, +, -, @
    gets a leading ' (OWASP); a negative number stays a number."""
    import pandas as pd

    _poison_csv(results, '=HYPERLINK("http://x","y")')
    main(["plot", f"results_dir={results}", "experiment=e", "only=iqm,threshold"])
    written = sorted((results / "e" / "figures").glob("*.csv"))  # the threshold table is left out when no seed reached one
    assert "iqm.csv" in [p.name for p in written], written
    for path in written:
        frame = pd.read_csv(path)
        text = frame.select_dtypes(exclude="number")
        assert '\'=HYPERLINK("http://x","y")' in text.to_numpy().ravel().tolist()
        assert not any(str(v).startswith(("=", "+", "@")) for v in text.to_numpy().ravel())


def test_safe_cell_neutralises_text_only():
    from imix_cli.running.files.writing import safe_cell, safe_frame

    assert safe_cell("=1+1") == "'=1+1" and safe_cell("@SUM(A1)") == "'@SUM(A1)" and safe_cell("+x") == "'+x" and safe_cell("-x") == "'-x"
    assert safe_cell("-12.5") == "-12.5" and safe_cell(-12.5) == -12.5 and safe_cell("cem") == "cem"
    assert safe_cell("a\nb\r\nc") == "a b c"
    import pandas as pd

    frame = safe_frame(pd.DataFrame({"score": [-12.5, 3.0], "algo": ["=cmd", "cem"]}))
    assert frame["score"].tolist() == [-12.5, 3.0] and frame["score"].dtype.kind == "f"
    assert frame["algo"].tolist() == ["'=cmd", "cem"]


def test_eval_csv_cells_are_neutralised(results, capsys):
    """eval.csv takes its ``run`` cell from the folder's name: a folder named like a formula is quoted."""
    import pandas as pd

    os.rename(results / "e" / RUN, results / "e" / "=cmd")
    assert main(["eval", f"results_dir={results}", "experiment=e", "episodes=2"]) == 0
    runs = pd.read_csv(results / "e" / "=cmd" / "eval.csv")["run"].tolist()
    assert runs and all(r == "'=cmd" for r in runs)


# ------------------------------------------------------------------ item 4: render streams its frames
GIF_MEMORY = """
import resource, sys
import numpy as np
from imix_cli.commands.render import write_gif

n = int(sys.argv[1])


def frames():
    for i in range(n):  # a bar moving across a 200 x 200 frame: every frame differs from the one before
        frame = np.zeros((200, 200, 3), dtype=np.uint8)
        frame[:, (3 * i) % 200] = (255, 128, 0)
        yield frame


with open("/dev/null", "wb") as fh:
    assert write_gif(fh, frames(), 50.0) == n
print(resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024)
"""


@pytest.mark.slow  # encodes 4,400 frames (~1-2 min)
def test_render_writes_a_gif_with_memory_independent_of_the_episode_length():
    """Once, render held every frame (1.84 GB for 859 frames at env.max_steps=5000). 3,600 more frames of
    120 kB each would be 430 MB more if held; streamed, the peak RSS stays within 40 MiB."""
    peaks = {}
    for n in (400, 4000):
        proc = subprocess.run([sys.executable, "-c", GIF_MEMORY, str(n)], capture_output=True, text=True, timeout=900)
        assert proc.returncode == 0, proc.stderr
        peaks[n] = int(proc.stdout.split()[-1])
    assert peaks[4000] - peaks[400] < 40, peaks


def test_render_writes_a_playable_mp4_through_the_writer(results, tmp_path, capsys):
    """The MP4 path streams to ffmpeg and writes through the same writer (needs ffmpeg on PATH)."""
    pytest.importorskip("pygame")
    ffmpeg = shutil.which("ffmpeg")
    if ffmpeg is None:
        pytest.skip("ffmpeg is not on PATH")
    out = tmp_path / "policy.mp4"
    assert main(["render", f"results_dir={results}", "experiment=e", "frames=20", f"out={out}"]) == 0
    probe = subprocess.run([ffmpeg, "-v", "error", "-i", str(out), "-f", "null", "-"], capture_output=True, text=True)
    assert probe.returncode == 0 and probe.stderr == "" and not [p for p in tmp_path.iterdir() if p.name.endswith(".tmp")]

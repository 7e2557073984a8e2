"""algo=ddpg without its extra: one line naming what to install, a non-zero exit, and no run
folder left behind for `imix status` to list. torch is hidden here, installed or not."""

import importlib.util

import pytest

import imix_cli
from imix_cli.commands.cli import main


@pytest.fixture
def no_torch(monkeypatch):
    find_spec = importlib.util.find_spec
    monkeypatch.setattr(importlib.util, "find_spec", lambda name, *a, **k: None if name.split(".")[0] == "torch" else find_spec(name, *a, **k))


def test_ddpg_without_torch_is_one_line_and_leaves_no_folder(tmp_path, capsys, no_torch):
    assert main(["run", "algo=ddpg", "env=continuous_cartpole", "seeds=2", "progress=false", f"results_dir={tmp_path}"]) == 1
    err = capsys.readouterr().err.strip()
    assert len(err.splitlines()) == 1 and "Traceback" not in err, err
    assert "algo=ddpg needs torch" in err and 'pip install torch==2.13.0 "imix-cli[ddpg]"' in err, err
    assert not any(tmp_path.iterdir())  # no experiment or run folder, no lock
    assert main(["status", f"results_dir={tmp_path}"]) == 1  # nothing to list
    assert "no runs" in capsys.readouterr().err


def test_the_library_call_says_the_same(tmp_path, no_torch):
    with pytest.raises(RuntimeError, match=r"algo=ddpg needs torch.*imix-cli\[ddpg\]"):
        imix_cli.run(algo="ddpg", env="continuous_cartpole", seeds=1, results_dir=str(tmp_path), echo=None)
    assert not any(tmp_path.iterdir())

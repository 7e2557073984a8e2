"""Sweep run names hide the defaults they ran with: a folder is named by the values that differ
from the paper's, so the sweep's table shows, next to each name, the swept values the name leaves out."""

from imix_cli.commands.cli import main
from imix_cli.running.config.compose import validate_overrides
from imix_cli.running.summary import hidden_values


def test_the_values_a_name_leaves_out_are_the_swept_ones_only():
    hidden = hidden_values(validate_overrides(["algo=snes,cem", "popsize=50,100"]))
    assert hidden == {
        "snes-cartpole-none": "generations=1000, popsize=50", "snes-cartpole-none-popsize=100": "generations=1000",
        "cem-cartpole-none": "generations=400, popsize=50", "cem-cartpole-none-popsize=100": "generations=400",
    }  # fmt: skip
    assert hidden_values(validate_overrides(["policy.hidden=[8,8],[16]"])) == {"snes-cartpole-none": "policy.hidden=[8, 8]"}
    assert hidden_values(validate_overrides(["seeds=2,3", "experiment=a,b"])) == {}  # no key of the results differs


def test_the_sweep_table_shows_them_next_to_the_names(tmp_path, capsys):
    args = ["run", "-m", "algo=cem", "popsize=50,8", "seeds=1", "generations=2", "workers=1", "progress=false", f"results_dir={tmp_path}"]
    assert main(args) == 0
    table = capsys.readouterr().out.split("sweep: ")[-1].splitlines()
    rows = [line.split("  ")[0] for line in table if line.startswith("cem-")]
    assert rows == ["cem-cartpole-none (popsize=50)", "cem-cartpole-none-popsize=8"], table

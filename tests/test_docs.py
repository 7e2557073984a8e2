"""The documentation: the site builds with --strict, the README stays short, no development-log
words, and the printed outputs the docs show are what the code prints (the cheap ones: a few s)."""

import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


@pytest.mark.docs
def test_the_site_builds_strictly(tmp_path):
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(tmp_path / "site")]
    env = {"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "MixingES" in api and "ask()" in api  # the API page is made from the docstrings
    assert (tmp_path / "site" / "results" / "paper" / "figures" / "efficiency_cartpole.png").exists()  # the hook's figures


def test_readme_is_short_and_its_links_exist():
    text = (ROOT / "README.md").read_text()
    assert len(text.splitlines()) <= 250
    for target in re.findall(r"\]\(([^)#]+)(?:#[^)]*)?\)", text):
        if not target.startswith("http"):
            assert (ROOT / target).exists(), target


DEVELOPMENT_LOG = re.compile(r"\bround \d+|\bthis round\b|\bissue \d+|\bthis session\b|\bsession's\b|\bfrom the `?\w+`? branch", re.I)


def test_no_development_log_words_in_readme_or_docs():
    found = [f"{p.relative_to(ROOT)}: {m.group(0)!r}" for p in PAGES for m in DEVELOPMENT_LOG.finditer(p.read_text())]
    assert found == []


@pytest.mark.slow  # two `imix run` processes, ~15-25 s
def test_the_docs_show_what_the_code_prints():
    from imix_cli.commands.docs_numbers import check

    assert check() == []

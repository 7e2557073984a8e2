"""The documentation: the site builds with --strict, the README stays short, no development-log
words, and the printed outputs and the README's figure data are what the code gives now."""

import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parent.parent
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").rglob("*.md"))]


@pytest.fixture(scope="module")
def site(tmp_path_factory):
    """The site, built once with --strict (a warning fails it)."""
    out = tmp_path_factory.mktemp("site") / "site"
    command = [sys.executable, "-m", "mkdocs", "build", "--strict", "-f", str(ROOT / "mkdocs.yml"), "-d", str(out)]
    env = {"NO_MKDOCS_2_WARNING": "1", "PATH": "/usr/bin:/bin", "PYTHONPATH": str(ROOT)}
    proc = subprocess.run(command, capture_output=True, text=True, cwd=ROOT, env=env)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return out


@pytest.mark.docs
def test_the_site_builds_strictly(site):
    tmp_path = site.parent
    api = (tmp_path / "site" / "api" / "index.html").read_text()
    assert "MixingES" in api and "ask()" in api  # the API page is made from the docstrings
    assert (tmp_path / "site" / "results" / "paper" / "figures" / "efficiency_cartpole.png").exists()  # the hook's figures
    hook = _hooks_module()
    in_site = sorted(p.relative_to(tmp_path / "site") for p in (tmp_path / "site" / "results").rglob("*.png"))
    assert in_site == [p.relative_to(ROOT) for p in hook.linked_figures(ROOT)]  # no local results/*/figures


def _api_sections(api: str) -> dict[str, str]:
    """The API page's HTML by documented object: ``{"imix_cli.core.mixing.ask_tell.MixingES": "<h2 ...> ... ", ...}`` (up to the next heading)."""
    parts = re.split(r'(?=<h[2-4] id="imix_cli\.)', api)
    return {re.match(r'<h[2-4] id="([^"]+)"', part).group(1): part for part in parts if part.startswith("<h")}


def _parameter_rows(section: str) -> list[tuple[str, str, str]]:
    """(name, type, default) of each row of the section's parameter table (the one with a Default column)."""
    import html

    rows = []
    for table in re.findall(r"<table>(.*?)</table>", section, re.S):
        header = [html.unescape(re.sub(r"<[^>]+>", "", h)).strip() for h in re.findall(r"<th[^>]*>(.*?)</th>", table, re.S)]
        if header[:2] != ["Name", "Type"] or "Default" not in header:
            continue
        for row in re.findall(r"<tr[^>]*>(.*?)</tr>", table, re.S)[1:]:
            cells = [" ".join(html.unescape(re.sub(r"<[^>]+>", " ", c)).split()) for c in re.findall(r"<td[^>]*>(.*?)</td>", row, re.S)]
            rows.append((cells[0], cells[1], cells[header.index("Default")]))
    return rows


@pytest.mark.docs
def test_the_api_page_shows_no_raw_roles_and_its_parameter_tables_are_the_signatures(site):
    """Sphinx roles (:class:`X`) are rendered, not shown raw; every parameter row names a parameter of the
    callable's signature (no "Every", "stays" read from prose), its default is the signature's, and its
    type admits that default (MixingES's alpha was typed "int" with default 3: a shared entry's)."""
    import ast
    import importlib
    import inspect

    api = (site / "api" / "index.html").read_text()
    assert not re.findall(r":(?:class|func|data|mod|meth|attr):", re.sub(r"<[^>]+>", "", api))
    checked = 0
    for name, section in _api_sections(api).items():
        rows = _parameter_rows(section)
        if not rows:
            continue
        module_name, _, attr = name.rpartition(".")
        try:
            obj = getattr(importlib.import_module(module_name), attr)
        except ImportError:  # a method: imix_cli.module.Class.method
            module_name, _, owner = module_name.rpartition(".")
            obj = getattr(getattr(importlib.import_module(module_name), owner), attr)
        parameters = inspect.signature(obj).parameters
        for row_name, row_type, default in rows:
            bare = row_name.lstrip("*")
            assert bare in parameters, f"{name}: {row_name!r} is not a parameter of {list(parameters)}"
            real = parameters[bare].default
            if real is inspect.Parameter.empty:
                assert default in ("required", "{}", "()"), (name, row_name, default)
                continue
            shown = ast.literal_eval(default)
            assert shown == real and type(shown) is type(real), f"{name}: {row_name} shows default {default}, the signature has {real!r}"
            if real is not None:  # numpy style writes a None default as "optional", which the page drops
                admitted = type(real).__name__
                assert admitted in row_type or (isinstance(real, str) and real in row_type), f"{name}: {row_name}'s type {row_type!r} does not admit {real!r}"
            checked += 1
    assert checked >= 8, checked


def test_make_docs_without_the_docs_extra_says_which_in_one_line(tmp_path):
    """After a plain `make install`, `make docs` names the extra to install (was: "No module named mkdocs")."""
    (tmp_path / "mkdocs.py").write_text("raise ImportError('not installed')\n")  # as if the docs extra were missing
    env = {**os.environ, "PYTHONPATH": str(tmp_path)}
    proc = subprocess.run(["make", "-s", "docs", f"PY={sys.executable}"], cwd=ROOT, env=env, capture_output=True, text=True, timeout=60)
    assert proc.returncode != 0 and 'pip install ".[docs]"' in proc.stderr and "make install-all" in proc.stderr, proc.stderr
    # make's own "make: ***" (or "make[1]: ***" under `make test`) line is make's, not imix's
    assert [line for line in proc.stderr.splitlines() if not line.startswith(("make:", "make["))] == [proc.stderr.splitlines()[0]], proc.stderr
    assert not (ROOT / "site").exists() or proc.stdout == ""


def _hooks_module():
    import importlib.util

    spec = importlib.util.spec_from_file_location("docs_hooks", ROOT / "docs" / "hooks.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_the_site_takes_only_the_figures_a_page_links_to(tmp_path):
    """A user's results/<experiment>/figures/ (after make reproduce-quick, say) never enter the site: only
    the figures a docs page links to (the committed paper figures) do."""
    (tmp_path / "docs" / "research").mkdir(parents=True)
    (tmp_path / "docs" / "research" / "page.md").write_text("![a](../../results/paper/figures/a.png) and ![gone](../../results/paper/figures/gone.png)")
    for name in ("paper/figures/a.png", "paper/figures/unlinked.png", "quick/figures/efficiency_cartpole.png"):
        (tmp_path / "results" / name).parent.mkdir(parents=True, exist_ok=True)
        (tmp_path / "results" / name).write_bytes(b"png")
    assert _hooks_module().linked_figures(tmp_path) == [tmp_path / "results" / "paper" / "figures" / "a.png"]


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


@pytest.mark.install  # the main job, the getting-started sweep and the first-steps figure's runs: a README-as-shown check, CI runs it once (make test-install)
def test_the_docs_show_what_the_code_prints():
    from imix_cli.commands.docs_numbers import check

    assert check() == []


def test_the_results_page_lists_every_provenance_mark_and_the_prose_names_no_commit():
    """docs/results.md is what ``make docs-numbers`` makes of the pages' provenance marks (a mark added, changed or
    removed without it fails here), and no page names a commit in its prose: a commit belongs in a mark."""
    import re

    from imix_cli.commands import docs_numbers

    assert docs_numbers.results_current(), "docs/results.md is out of date: make docs-numbers (or docs_numbers.write_results_page())"
    rows = docs_numbers.provenance_rows()
    assert rows and all(re.fullmatch(r"[0-9a-f]{7,40}", row["commit"]) for row in rows)
    stamp = re.compile(r"\b(?:commit|at) [0-9a-f]{7,40}\b")
    found = [f"{p.relative_to(ROOT)}: {m.group(0)!r}" for p in PAGES for m in stamp.finditer(docs_numbers._MARK.sub("", p.read_text()))]
    assert found == []

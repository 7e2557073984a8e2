"""mkdocs hook: the paper's figures that the pages show (results/<experiment>/figures/*.png, committed
for results/paper*/) are part of the site, at the same paths, without a second copy under docs/.

Only the figures a page links to are added: a user's own results (results/quick/ after `make
reproduce-quick`, results/first/, ...) stay out of the site even though they sit in the same tree.
"""

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
FIGURE_LINK = re.compile(r"(?:\.\./)*(results/[\w.-]+/figures/[\w.-]+\.png)")


def linked_figures(root: Path) -> list[Path]:
    """The results/*/figures/*.png that a page under docs/ links to and that exist, each once."""
    linked = {match for page in sorted((root / "docs").rglob("*.md")) for match in FIGURE_LINK.findall(page.read_text())}
    return [root / path for path in sorted(linked) if (root / path).is_file()]


def on_files(files, config):
    from mkdocs.structure.files import File

    for png in linked_figures(ROOT):
        files.append(File(png.relative_to(ROOT).as_posix(), str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files

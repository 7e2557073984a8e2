"""mkdocs hook: the paper's committed figures (results/*/figures/*.png) are part of the site, at the
same paths, so that pages show them without a second copy under docs/."""

from pathlib import Path

from mkdocs.structure.files import File

ROOT = Path(__file__).resolve().parent.parent


def on_files(files, config):
    for png in sorted((ROOT / "results").glob("*/figures/*.png")):
        files.append(File(png.relative_to(ROOT).as_posix(), str(ROOT), config["site_dir"], config["use_directory_urls"]))
    return files

"""Write constraints.txt: the exact versions of what ``imix-cli[all]`` (and torch) pulls into this venv.

Why a pruned freeze and not ``pip freeze``: a development venv also holds tools nobody's install
needs (docs builders, profilers); a constraint on them would only get in the way. The closure is
taken from the installed distributions' own requirements, extras and markers included, starting
at imix-cli with the extras given (default ``all``). Local version labels (torch's ``+cpu``) are
dropped, so that the pin matches the CPU wheel and PyPI's alike.

    python tools/freeze_constraints.py [--extras all] > constraints.txt
"""

from __future__ import annotations

import argparse
import importlib.metadata as metadata
import platform
import sys

from packaging.requirements import Requirement
from packaging.utils import canonicalize_name


def closure(extras: set[str]) -> dict[str, metadata.Distribution]:
    """Every installed distribution imix-cli[extras] needs, by canonical name."""
    found: dict[str, tuple[metadata.Distribution, set[str]]] = {}
    stack = [("imix-cli", set(extras))]
    while stack:
        name, wanted = stack.pop()
        key = canonicalize_name(name)
        if key in found and wanted <= found[key][1]:
            continue
        dist = metadata.distribution(name)
        found[key] = (dist, (found[key][1] if key in found else set()) | wanted)
        for line in dist.requires or []:
            req = Requirement(line)
            if req.marker is not None and not any(req.marker.evaluate({"extra": e}) for e in (wanted or {""})):
                continue
            stack.append((req.name, set(req.extras)))
    return {key: dist for key, (dist, _) in found.items() if key != "imix-cli"}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--extras", default="all", help="comma-separated extras of imix-cli (default: all)")
    extras = set(parser.parse_args().extras.split(","))
    print('# The tested stack: exact versions of everything `pip install ".[all]"` (+ torch) installs, as in the venv')
    print(f"# that ran the tests and produced the published numbers (Python {platform.python_version()}, {platform.machine()} Linux).")
    print("# `make install` / `make install-all` install with `-c constraints.txt`; `pip install .` stays unpinned.")
    print("# Regenerate in a venv with imix-cli[all] installed: python tools/freeze_constraints.py > constraints.txt")
    for _, dist in sorted(closure(extras).items()):
        print(f"{dist.metadata['Name']}=={dist.version.split('+')[0]}")


if __name__ == "__main__":
    sys.exit(main())

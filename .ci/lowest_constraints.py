"""Prints a pip constraints file that pins each of graft's dependencies to its floor.

pip has no lowest-version resolution, so `make test-lowest` installs graft with
``pip install -c`` this file: every dependency at the lowest release pyproject.toml allows.
A dependency without a ``>=`` floor is refused in one line, as is one whose floor is held
(``--hold NAME``: installed by other means, e.g. torch's CPU build, which is not on PyPI).

    python .ci/lowest_constraints.py [--hold NAME ...] > constraints.txt
"""

from __future__ import annotations

import argparse
import re
import sys
import tomllib
from pathlib import Path

PYPROJECT = Path(__file__).resolve().parent.parent / "pyproject.toml"
REQUIREMENT = re.compile(r"^\s*([A-Za-z0-9][A-Za-z0-9._-]*)\s*(\[[^\]]*\])?\s*([^;]*)")


def floors(dependencies: list[str], hold: set[str]) -> list[str]:
    """``name==floor`` for each dependency (its ``>=`` bound), the held ones left out."""
    lines = []
    for dependency in dependencies:
        match = REQUIREMENT.match(dependency)
        if match is None:
            raise ValueError(f"dependency {dependency!r}: not a requirement pip reads")
        name, specifiers = match.group(1), match.group(3)
        if name.lower() in hold:
            continue
        lower = [s.strip()[2:].strip() for s in specifiers.split(",") if s.strip()[:2] == ">="]
        if len(lower) != 1:
            raise ValueError(f"dependency {dependency!r}: needs exactly one '>=' floor")
        lines.append(f"{name}=={lower[0]}")
    return lines


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--hold", action="append", default=[], help="a dependency left out")
    args = parser.parse_args()
    project = tomllib.loads(PYPROJECT.read_text())["project"]
    try:
        lines = floors(project["dependencies"], {name.lower() for name in args.hold})
    except ValueError as error:
        sys.exit(f"{PYPROJECT.name}: {error}")
    print("\n".join(lines))


if __name__ == "__main__":
    main()

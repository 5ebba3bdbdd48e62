"""Refresh the lock (`constraints.txt`) and docs/environment.md's "Tested versions" together.

    .venv/bin/python runners/refresh_lock.py              # a fresh venv: the newest set
    .venv/bin/python runners/refresh_lock.py --from .venv # lock what this venv has instead

The first form builds a throwaway venv in a temporary folder, installs torch pinned (the
lock's version, or `--torch`; an unpinned torch can pull a multi-GB CUDA build), then
`-e ".[dev]"` with no constraints, so pip takes the newest release of everything else. Either
form writes that set, every transitive dependency pinned with `==` (pip and the editable rwalk
left out), to `constraints.txt`, and each direct dependency's locked version into the table.
Then reinstall from the new lock and run the whole suite before committing both files.
"""

from __future__ import annotations

import json
import re
import subprocess
import sys
import tempfile
from dataclasses import dataclass
from pathlib import Path

import tomllib
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
LOCK = ROOT / "constraints.txt"
DOCS = ROOT / "docs" / "environment.md"
SECTION = "## Tested versions"
HEADER = """\
# The tested set: every package that `pip install -e ".[dev]"` installs, pinned (a pip
# constraints file; CPython 3.11, Linux x86-64). Install torch first, then the rest:
#   pip install -c constraints.txt torch==<torch's pin below>
#   pip install -c constraints.txt -e ".[dev]"
# Written by runners/refresh_lock.py (docs/environment.md, "Tested versions"): not by hand.
"""
NOT_INSTALLED = "not installed in the tested set"


def read_lock(text: str) -> dict[str, str]:
    """Canonical name -> version of each `name==version` line (comments and blanks skipped)."""
    pins: dict[str, str] = {}
    for line in text.splitlines():
        line = line.split("#", 1)[0].strip()
        if line:
            requirement = Requirement(line)
            versions = [s.version for s in requirement.specifier if s.operator == "=="]
            if len(versions) != 1 or len(requirement.specifier) != 1:
                raise ValueError(f"lock line {line!r} is not name==version")
            pins[canonicalize_name(requirement.name)] = versions[0]
    return pins


def lock_text(installed: dict[str, str]) -> str:
    """The lock for `installed` (name -> version): sorted `name==version` lines under HEADER.
    Local labels go (`2.13.0+cpu` -> `2.13.0`: `==2.13.0` still admits the CPU wheel)."""
    pins = {canonicalize_name(name): Version(v).public for name, v in installed.items()}
    lines = [f"{name}=={pins[name]}" for name in sorted(pins)]
    return HEADER + "\n".join(lines) + "\n"


def direct_dependencies(project: dict) -> dict[str, list[str]]:
    """Name as pyproject writes it -> the extras that list it ([] for a core dependency);
    core dependencies first, then each extra's new names, in pyproject's order."""
    extras: dict[str, list[str]] = {Requirement(t).name: [] for t in project["dependencies"]}
    for extra, texts in project.get("optional-dependencies", {}).items():
        for text in texts:
            extras.setdefault(Requirement(text).name, []).append(extra)
    return extras


def rewrite_tested_versions(markdown: str, project: dict, pins: dict[str, str]) -> str:
    """`markdown` with the table of its "Tested versions" section rebuilt: a row per direct
    dependency of `project` (pyproject's [project] table), its version from `pins` (canonical
    name -> version). A note after an old cell's version stays (`2.13.0 (CPU wheel)`); a
    dependency the lock lacks (an extra outside dev) keeps its old version, marked not
    installed. The text around the table is left as it is."""
    head, rest = markdown.split(SECTION, 1)
    match = re.search(r"^\| package \| version \| extra \|\n(?:\|.*\n?)*", rest, re.MULTILINE)
    if match is None:
        raise ValueError(f"no '| package | version | extra |' table under {SECTION!r}")
    old = {
        canonicalize_name(name): cell.strip()
        for name, cell in re.findall(r"^\| ([^|]+?) \| ([^|]*) \|", match.group(), re.MULTILINE)
    }
    rows = ["| package | version | extra |", "| --- | --- | --- |"]
    for name, extras in direct_dependencies(project).items():
        key = canonicalize_name(name)
        old_cell = old.get(key, "")
        version, _, note = ("" if old_cell == NOT_INSTALLED else old_cell).partition(" ")
        if key in pins:
            cell = pins[key] if NOT_INSTALLED in note else f"{pins[key]} {note}".strip()
        elif version:
            cell = f"{version} ({NOT_INSTALLED})"
        else:
            cell = NOT_INSTALLED
        extra_cell = f" {', '.join(extras)} " if extras else " "
        rows.append(f"| {name} | {cell} |{extra_cell}|")
    table = "\n".join(rows) + ("\n" if match.group().endswith("\n") else "")
    return head + SECTION + rest[: match.start()] + table + rest[match.end() :]


def installed_set(python: Path) -> dict[str, str]:
    """Name -> version of what `python`'s environment has, less pip and editable installs."""
    out = subprocess.run(
        [str(python), "-m", "pip", "list", "--format=json", "--exclude-editable"],
        check=True,
        capture_output=True,
        text=True,
    ).stdout
    return {p["name"]: p["version"] for p in json.loads(out) if p["name"] != "pip"}


def fresh_set(torch: str) -> dict[str, str]:
    """The set a fresh venv gets today: torch==`torch` first, then `.[dev]` unconstrained."""
    with tempfile.TemporaryDirectory(prefix="rwalk-lock-") as folder:
        venv = Path(folder) / "venv"
        subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
        pip = [str(venv / "bin" / "python"), "-m", "pip", "install", "-q"]
        subprocess.run([*pip, f"torch=={torch}"], check=True)
        subprocess.run([*pip, "-e", f"{ROOT}[dev]"], check=True)
        return installed_set(venv / "bin" / "python")


@dataclass(frozen=True)
class RefreshArgs:
    """Refresh constraints.txt and docs/environment.md's table together."""

    venv: Path | None = None
    """lock this venv's set instead of a fresh one's (also --from)"""
    torch: str | None = None
    """torch version for a fresh venv (default: the lock's)"""


def main(argv: list[str] | None = None) -> None:
    from rwalk.cli import parse, usage_error

    prog = "python runners/refresh_lock.py"
    args = parse(RefreshArgs, argv, prog=prog, description=__doc__, aliases={"--from": "--venv"})
    before = read_lock(LOCK.read_text()) if LOCK.is_file() else {}
    if args.venv is not None:
        installed = installed_set(args.venv / "bin" / "python")
    else:
        torch = args.torch or before.get("torch")
        if torch is None:
            usage_error(prog, "no torch version: pass --torch (there is no lock to take it from)")
        installed = fresh_set(torch)
    LOCK.write_text(lock_text(installed))
    pins = read_lock(LOCK.read_text())
    project = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
    DOCS.write_text(rewrite_tested_versions(DOCS.read_text(), project, pins))
    if before:  # what moved
        for name in sorted(before.keys() | pins.keys()):
            if before.get(name) != pins.get(name):
                print(f"{name}: {before.get(name, '-')} -> {pins.get(name, '-')}")
    print(f"wrote {LOCK.relative_to(ROOT)} ({len(pins)} packages) and {DOCS.relative_to(ROOT)}")


if __name__ == "__main__":
    main()

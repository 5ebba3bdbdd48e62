"""pyproject's bounds hold for the tested set, and docs/environment.md lists that set."""

import re
from importlib import metadata
from pathlib import Path

import tomllib
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]


def _requirements() -> list[tuple[str, Requirement]]:
    """(extra or "", requirement) for every dependency and optional dependency."""
    rows = [("", Requirement(text)) for text in PROJECT["dependencies"]]
    for extra, texts in PROJECT["optional-dependencies"].items():
        rows += [(extra, Requirement(text)) for text in texts]
    return rows


def _installed(name: str) -> Version | None:
    try:
        return Version(metadata.version(name))
    except metadata.PackageNotFoundError:
        return None


def _tested_table() -> dict[str, str]:
    """Package -> version cell of the "Tested versions" table."""
    text = (ROOT / "docs" / "environment.md").read_text()
    section = text.split("## Tested versions", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| ([a-z][a-z0-9._-]*) \| ([^|]+) \|", section, flags=re.MULTILINE)
    return {canonicalize_name(name): cell.strip() for name, cell in rows if name != "package"}


def test_lower_bounds_are_the_installed_versions():
    for extra, requirement in _requirements():
        version = _installed(requirement.name)
        if version is None:
            assert extra, f"dependency {requirement} is not installed"
            continue  # an extra this environment does not install (moviepy)
        assert requirement.specifier.contains(version, prereleases=True), (requirement, version)
        # The lower bound is the tested version (to the precision written), not a guess below it.
        (lower,) = [Version(s.version) for s in requirement.specifier if s.operator == ">="]
        assert lower.release == version.release[: len(lower.release)], (requirement, version)


def test_the_tested_versions_table_is_the_installed_set():
    table = _tested_table()
    for _, requirement in _requirements():
        assert canonicalize_name(requirement.name) in table, f"{requirement.name} not in the table"
    for name, cell in table.items():
        version = _installed(name)
        if "not installed" in cell:
            assert version is None, name
            continue
        assert version is not None and cell.split()[0] == version.public, (name, cell, version)


def test_every_console_script_is_a_main_and_the_readme_uses_only_those():
    import importlib

    scripts = PROJECT["scripts"]
    for name, target in scripts.items():
        module, function = target.split(":")
        assert callable(getattr(importlib.import_module(module), function)), name
        shim = ROOT / "runners" / f"{module.rsplit('.', 1)[1]}.py"
        assert shim.is_file(), f"{name}: no checkout shim {shim}"
    used = set(re.findall(r"\brwalk-[a-z0-9-]+", (ROOT / "README.md").read_text()))
    assert used and used <= set(scripts), used - set(scripts)

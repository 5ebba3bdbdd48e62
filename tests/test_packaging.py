"""The lock (constraints.txt), pyproject's bounds and docs/environment.md's "Tested versions"
table agree; the installed set is compared with the lock only where it was installed from it."""

import importlib.util
import re
import sys
from importlib import metadata
from pathlib import Path

import pytest
import tomllib
from packaging.requirements import Requirement
from packaging.utils import canonicalize_name
from packaging.version import Version

ROOT = Path(__file__).resolve().parents[1]
PROJECT = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]
NOT_INSTALLED = "not installed in the tested set"


def _refresh_lock():
    """runners/refresh_lock.py as a module (by path: pytest may not put the root on sys.path)."""
    path = ROOT / "runners" / "refresh_lock.py"
    spec = importlib.util.spec_from_file_location("refresh_lock", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module  # where its dataclasses look their module up
    spec.loader.exec_module(module)
    return module


REFRESH = _refresh_lock()
LOCK = REFRESH.read_lock((ROOT / "constraints.txt").read_text())


def _requirements() -> list[tuple[str, Requirement]]:
    """(extra or "", requirement) for every dependency and optional dependency."""
    rows = [("", Requirement(text)) for text in PROJECT["dependencies"]]
    for extra, texts in PROJECT["optional-dependencies"].items():
        rows += [(extra, Requirement(text)) for text in texts]
    return rows


def _tested_table() -> dict[str, str]:
    """Package -> version cell of the "Tested versions" table."""
    text = (ROOT / "docs" / "environment.md").read_text()
    section = text.split("## Tested versions", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| ([a-z][a-z0-9._-]*) \| ([^|]+) \|", section, flags=re.MULTILINE)
    return {canonicalize_name(name): cell.strip() for name, cell in rows if name != "package"}


def test_the_lock_the_table_and_the_bounds_agree():
    """Each direct dependency, extras included, is in the table; where the table says it is
    installed, the lock pins the same version and pyproject's bounds admit it; where the
    table says it is not (an extra outside dev), the lock does not have it. Each `.[dev]`
    dependency is locked, and the table lists nothing pyproject does not name."""
    table = _tested_table()
    direct = {canonicalize_name(requirement.name) for _, requirement in _requirements()}
    assert set(table) <= direct, f"not a dependency in pyproject: {set(table) - direct}"
    for extra, requirement in _requirements():
        name = canonicalize_name(requirement.name)
        assert name in table, f"{requirement.name} not in the table"
        if NOT_INSTALLED in table[name]:
            assert extra not in ("", "dev"), f"{requirement}: `.[dev]` installs it"
            assert name not in LOCK, f"{name} is locked but the table says not installed"
            continue
        assert name in LOCK, f"{requirement} is not in constraints.txt"
        assert table[name].split()[0] == LOCK[name], (name, table[name], LOCK[name])
        assert requirement.specifier.contains(LOCK[name], prereleases=True), (
            f"{requirement} does not admit the locked {LOCK[name]}"
        )


def test_the_table_is_what_a_refresh_writes_from_the_lock():
    """runners/refresh_lock.py's rewrite, applied to the docs and the committed lock, changes
    nothing: rows, order, extras and notes are the ones a refresh writes."""
    text = (ROOT / "docs" / "environment.md").read_text()
    assert REFRESH.rewrite_tested_versions(text, PROJECT, LOCK) == text


def test_the_lock_is_as_refresh_lock_writes_it():
    """Every line pins one package with `==`, torch among them, sorted, under the header."""
    text = (ROOT / "constraints.txt").read_text()
    assert "torch" in LOCK
    assert REFRESH.lock_text(LOCK) == text, "constraints.txt is not as refresh_lock writes it"


#: The file `.ci/run` writes into a venv it built from the lock.
FROM_LOCK = "rwalk-installed-from-lock"


def test_the_installed_set_is_the_lock_when_installed_from_it():
    """Only where it holds by construction: `.ci/run` builds a fresh venv with
    `pip install -c constraints.txt` and marks it so (the file FROM_LOCK in the venv), so
    there every installed distribution (pip, wheel and the editable rwalk aside) must be
    the locked version, and every locked one installed: this catches a lock that misses a
    transitive dependency (pip would have taken its newest release) or that pip could not
    honour. Elsewhere (a developer's older venv, a plain `pip install -e ".[dev]"` on a day a
    dependency published a patch) the installed versions may differ from the lock and this
    check skips; the rest of the suite says whether that set works."""
    if not (Path(sys.prefix) / FROM_LOCK).is_file():
        pytest.skip(f"no {FROM_LOCK} in {sys.prefix}: this venv was not built from the lock")
    installed = {
        canonicalize_name(dist.metadata["Name"]): Version(dist.version).public
        for dist in metadata.distributions()
    }
    for name in ("rwalk", "pip", "wheel"):
        installed.pop(name, None)
    unlocked = {name: v for name, v in installed.items() if LOCK.get(name) != v}
    assert not unlocked, f"installed but not locked at that version: {unlocked}"
    missing = set(LOCK) - set(installed)
    assert not missing, f"locked but not installed: {missing}"


def test_rewrite_tested_versions_keeps_notes_and_marks_extras_outside_the_lock():
    project = {
        "dependencies": ["torch>=2.13", "tyro>=1.0"],
        "optional-dependencies": {"dev": ["pytest>=9"], "ray": ["ray[default]>=2.60"]},
    }
    markdown = (
        "# Env\n\n## Tested versions\n\nIntro.\n\n"
        "| package | version | extra |\n| --- | --- | --- |\n"
        "| torch | 2.13.0 (CPU wheel) | |\n"
        "| pytest | 9.1.0 | dev |\n"
        "| ray | 2.60.0 (not installed in the tested set) | ray |\n"
        "| gone | 1.0 | |\n"
        "\nAfter.\n\n## Next\n\n| package | version | extra |\n| keep | 0 | |\n"
    )
    pins = {"torch": "2.14.0", "tyro": "1.0.17", "pytest": "9.2.0", "numpy": "2.4.6"}
    expected = (
        "# Env\n\n## Tested versions\n\nIntro.\n\n"
        "| package | version | extra |\n| --- | --- | --- |\n"
        "| torch | 2.14.0 (CPU wheel) | |\n"
        "| tyro | 1.0.17 | |\n"
        "| pytest | 9.2.0 | dev |\n"
        "| ray | 2.60.0 (not installed in the tested set) | ray |\n"
        "\nAfter.\n\n## Next\n\n| package | version | extra |\n| keep | 0 | |\n"
    )
    assert REFRESH.rewrite_tested_versions(markdown, project, pins) == expected
    # A dev dependency moved to an extra only keeps its old version, marked not installed.
    del pins["pytest"]
    moved = REFRESH.rewrite_tested_versions(markdown, project, pins)
    assert "| pytest | 9.1.0 (not installed in the tested set) | dev |" in moved


def test_lock_text_pins_exactly_and_drops_local_labels():
    text = REFRESH.lock_text({"torch": "2.13.0+cpu", "Farama-Notifications": "0.0.6"})
    assert text.startswith("#")
    assert text.endswith("farama-notifications==0.0.6\ntorch==2.13.0\n")
    assert REFRESH.read_lock(text) == {"farama-notifications": "0.0.6", "torch": "2.13.0"}
    with pytest.raises(ValueError, match="not name==version"):
        REFRESH.read_lock("torch>=2.13\n")


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

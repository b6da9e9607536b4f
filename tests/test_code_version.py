"""A stage's code version: the source of the modules it runs, found through their imports."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

from toolkit import code_version as cv


@pytest.fixture
def package(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Iterator[Path]:
    """A small package named like this one: ``a`` imports ``b`` (in a parenthesised list,
    by alias) and, for type checking only, ``c``; ``d`` is a subpackage module."""
    root = tmp_path / cv.PACKAGE
    (root / "sub").mkdir(parents=True)
    (root / "__init__.py").write_text('"""pkg"""\n')
    (root / "sub" / "__init__.py").write_text("")
    (root / "a.py").write_text(
        "from typing import TYPE_CHECKING\n"
        f"from {cv.PACKAGE} import (\n    b as bee,  # the one it needs\n)\n"
        "if TYPE_CHECKING:\n"
        f"    from {cv.PACKAGE}.c import Thing\n"
        "def f():\n"
        f"    import {cv.PACKAGE}.sub.d as d\n"
        "    return d\n"
    )
    (root / "b.py").write_text("X = 1\n")
    (root / "c.py").write_text("class Thing: ...\n")
    (root / "sub" / "d.py").write_text("Y = 2\n")
    monkeypatch.setattr(cv, "PACKAGE_DIR", root)
    cv._closure.cache_clear()
    cv._version.cache_clear()
    yield root
    cv._closure.cache_clear()
    cv._version.cache_clear()


def _version(root: str) -> str:
    cv._closure.cache_clear()
    cv._version.cache_clear()
    return cv.code_version([root])


def test_a_modules_imports_at_run_time_are_its_code(package: Path) -> None:
    p = cv.PACKAGE
    assert cv.modules_of([f"{p}.a"]) == (p, f"{p}.a", f"{p}.b", f"{p}.sub", f"{p}.sub.d")


def test_the_version_moves_with_the_code_it_runs_and_only_that(package: Path) -> None:
    p = cv.PACKAGE
    before = _version(f"{p}.a")
    assert len(before) == 64 and before == _version(f"{p}.a")
    (package / "c.py").write_text("class Thing:\n    x = 1\n")  # imported for types only
    assert _version(f"{p}.a") == before
    (package / "sub" / "d.py").write_text("Y = 3\n")  # imported inside a function
    after = _version(f"{p}.a")
    assert after != before
    (package / "__init__.py").write_text('"""pkg, changed"""\n')  # runs before any module
    assert _version(f"{p}.a") != after


def test_each_stage_covers_its_own_modules_not_the_command_line_or_the_simulator() -> None:
    from toolkit.stages.registry import stages

    for stage in stages():
        roots = {stage.compute.__module__, stage.recall.__module__}
        modules = cv.modules_of(roots)
        assert roots <= set(modules), stage.name
        assert "toolkit.config" in modules, stage.name
        assert not [m for m in modules if m.startswith(("toolkit.cli", "toolkit.sim.simulate"))]
        assert len(stage.code_version) == 64
    tables = cv.modules_of(["toolkit.stages.tables"])
    assert "toolkit.stages.tables_points" in tables
    assert "toolkit.fusion.ukf" not in tables

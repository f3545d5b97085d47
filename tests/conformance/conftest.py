"""Collect the family modules (`<role>_<family>.py`, named for the family, not `test_*`) so
their tests run in the suite like any other."""

from __future__ import annotations

from pathlib import Path

import pytest

HERE = Path(__file__).parent
NOT_FAMILIES = {"table.py", "conftest.py", "__init__.py"}


def pytest_collect_file(file_path: Path, parent: pytest.Collector) -> pytest.Module | None:
    if (file_path.parent == HERE and file_path.suffix == ".py"
            and file_path.name not in NOT_FAMILIES
            and not file_path.name.startswith(("_", "test_"))):
        return pytest.Module.from_parent(parent, path=file_path)
    return None

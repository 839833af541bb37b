"""Fixtures for the FE-RIS tests: the gmsh writer of tests/fem (loaded by path)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


@pytest.fixture(scope="session")
def gmsh_text():
    path = Path(__file__).parents[1] / "fem" / "gmsh_text.py"
    spec = importlib.util.spec_from_file_location("rothe_tests_gmsh_text", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod

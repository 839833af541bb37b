"""Fixtures shared by the test folders: gmsh files written by the test itself (no binaries)."""

from __future__ import annotations

import importlib.util
from pathlib import Path

import pytest


def load_gmsh_text():
    path = Path(__file__).parent / "fem" / "gmsh_text.py"
    spec = importlib.util.spec_from_file_location("rothe_tests_gmsh_text", path)
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


@pytest.fixture(scope="session")
def gmsh_text():
    return load_gmsh_text()

"""The package docstring and the user docs stand on their own (issue 10, item 4)."""

import re
from pathlib import Path

import pytest

import rothe

ROOT = Path(__file__).resolve().parents[1]
USER_DOCS = sorted((ROOT / "docs").glob("*.md")) + [ROOT / "README.md"]


def test_help_of_the_package_points_to_both_families_the_cli_and_the_docs():
    doc = rothe.__doc__
    for needle in (
        "rothe.eld",
        "run_eld",
        "run_ris",
        "SpaceAdaptivity",
        "rothe sweep",
        "rothe resume",
        "docs/eld.md",
        "docs/robustness.md",
        "docs/adaptivity.md",
    ):
        assert needle in doc, needle
    # every document the docstring names exists
    for name in re.findall(r"docs/\w+\.md", doc):
        assert (ROOT / name).is_file(), name


@pytest.mark.skipif(not (ROOT / "docs").is_dir(), reason="docs/ is not in this installation")
@pytest.mark.parametrize("path", USER_DOCS, ids=lambda p: p.name)
def test_user_docs_cite_the_papers_not_internal_documents(path):
    text = path.read_text(encoding="utf-8")
    internal = re.findall(r"SPEC\b[^\n]{0,20}|PERFORMANCE-NOTES|\.\./shared", text)
    assert not internal, f"{path.name} cites internal documents: {internal[:3]}"

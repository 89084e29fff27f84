"""The documentation stands alone: every reference resolves inside the repository."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
SOURCE_DIRS = ["framework", "plugins", "kernels", "benchmarks", "tests", "examples", "docs", "tools"]
TEXT_SUFFIXES = {".py", ".md", ".yaml", ".toml", ".cl", ".glsl", ".sh"}


def _text_files():
    files = [ROOT / "README.md", ROOT / "CHANGELOG.md", ROOT / "pyproject.toml"]
    for folder in SOURCE_DIRS:
        files += [p for p in (ROOT / folder).rglob("*") if p.suffix in TEXT_SUFFIXES and "node" not in p.parts
                  and "out" not in p.parts]
    return [p for p in files if p.is_file() and p != Path(__file__).resolve()]


def test_nothing_points_outside_the_repository():
    """No docstring or page cites files that are not in the repository (design notes, a shared folder)."""
    bad = re.compile(r"ALGORITHMS\.md|DESIGN\.md|shared/(docs|data|papers|device)\b")
    hits = [f"{p.relative_to(ROOT)}:{i}" for p in _text_files()
            for i, line in enumerate(p.read_text(errors="replace").splitlines(), 1) if bad.search(line)]
    assert hits == []


def test_every_paper_tag_is_defined_in_the_references():
    """``[P10]``, ``[S09]``... used anywhere are defined in docs/algorithms.md's references section."""
    algorithms = (ROOT / "docs" / "algorithms.md").read_text()
    references = algorithms.split("## References", 1)[1]
    defined = set(re.findall(r"\*\*\[([A-Z]\d\d)\]\*\*", references))
    assert {"P10", "S09"} <= defined
    used = {tag for p in _text_files() for tag in re.findall(r"\[([A-Z]\d\d)\b", p.read_text(errors="replace"))}
    assert used - defined == set()


def test_every_author_year_citation_is_in_the_references():
    """Author-year citations in docstrings and pages name a paper listed in docs/algorithms.md."""
    references = (ROOT / "docs" / "algorithms.md").read_text().split("## References", 1)[1]
    cite = re.compile(r"\b([A-Z][a-z]+)(?: (?:&|and) [A-Z][a-z]+| et al\.)?,? (19[5-9]\d|20[0-2]\d)\b")
    # Software and data sets cited by year are not papers.
    not_papers = {"Athlon", "Core", "Mesa", "Python", "Khronos", "Eurographics", "December", "November", "Measured"}
    missing = set()
    for p in _text_files():
        for author, year in cite.findall(p.read_text(errors="replace")):
            if author in not_papers:
                continue
            if author not in references or year not in references:
                missing.add(f"{author} {year} ({p.relative_to(ROOT)})")
    assert missing == set()


@pytest.mark.parametrize("page", sorted(p.name for p in (ROOT / "docs").glob("*.md")) + ["../README.md"])
def test_relative_links_resolve(page):
    """Every relative Markdown link of a page points at a file of the repository."""
    path = (ROOT / "docs" / page).resolve()
    text = path.read_text()
    for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text):
        if re.match(r"[a-z]+://", target):
            continue
        assert (path.parent / target).exists(), f"{page}: link to {target} does not resolve"

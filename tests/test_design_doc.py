"""The design document the docstrings cite ("DESIGN §N") is in the
repository, and every section they cite exists there."""
import re
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
DESIGN = ROOT / "docs" / "design.md"


def _cited_sections() -> dict:
    cited = {}
    for folder in ("integrators", "rectify", "episcatter", "experiments", "scenes"):
        for path in (ROOT / folder).rglob("*.py"):
            for m in re.finditer(r"DESIGN §(\d+)", path.read_text(encoding="utf-8")):
                cited.setdefault(int(m.group(1)), []).append(path.relative_to(ROOT).as_posix())
    return cited


def test_every_cited_design_section_exists():
    text = DESIGN.read_text(encoding="utf-8")
    sections = {int(n) for n in re.findall(r"^## (\d+)\. ", text, flags=re.M)}
    cited = _cited_sections()
    assert cited, "no docstring cites DESIGN §N any more: drop this test"
    missing = {n: files[:3] for n, files in cited.items() if n not in sections}
    assert not missing, f"cited but not in docs/design.md: {missing}"


def test_design_doc_names_modules_that_exist():
    """Every `integrators/...`, `rectify/...` or `experiments.x` module the
    document names is a file of the repository."""
    text = DESIGN.read_text(encoding="utf-8")
    for rel in re.findall(r"`((?:integrators|rectify|episcatter)/[\w/]+\.py)`", text):
        assert (ROOT / rel).exists(), rel
    for name in re.findall(r"experiments\.(\w+)", text):
        assert (ROOT / "experiments" / f"{name}.py").exists(), name


def test_no_issue_numbers_in_library_docstrings():
    """Docstrings state the contract and cite the papers and the design;
    issue numbers belong to the tracker and closing notes."""
    hits = []
    for folder in ("integrators", "rectify", "episcatter"):
        for path in (ROOT / folder).rglob("*.py"):
            for i, line in enumerate(path.read_text(encoding="utf-8").splitlines(), 1):
                if re.search(r"\bissue \d+|\(issue\b", line, flags=re.I):
                    hits.append(f"{path.relative_to(ROOT)}:{i}")
    assert not hits, hits


DOCUMENTS = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md")),
             *sorted((ROOT / "results").glob("*/README.md"))]


def test_readme_is_a_users_guide_of_at_most_400_lines():
    assert len((ROOT / "README.md").read_text(encoding="utf-8").splitlines()) <= 400


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_documents_cite_no_issue_numbers_or_sessions(path):
    """Documents are for users and the next engineer: no tracker numbers,
    no session logs (the design document may name its own sections)."""
    bad = [line for line in path.read_text(encoding="utf-8").splitlines()
           if re.search(r"\b[Ii]ssue \d+|\(#\d+\)|\b[Ss]ession \d+|\bthis session\b", line)]
    assert not bad, f"{path.name}: {bad[:3]}"


@pytest.mark.parametrize("path", DOCUMENTS, ids=lambda p: str(p.relative_to(ROOT)))
def test_relative_links_resolve(path):
    text = path.read_text(encoding="utf-8")
    missing = [target for target in re.findall(r"\]\(([^)#\s]+)(?:#[^)]*)?\)", text)
               if "://" not in target and not target.startswith("mailto:")
               and not (path.parent / target).exists()]
    assert not missing, f"{path.relative_to(ROOT)} links to missing {missing}"

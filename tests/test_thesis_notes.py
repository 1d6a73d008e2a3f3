"""Citations of docs/thesis-notes.md: every cited note exists, and no citation points outside the
repository (the old private reading notes, "ERRATA n", that no checkout has)."""

import re
import subprocess
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
NOTES = ROOT / "docs" / "thesis-notes.md"
#: A citation: the file name, then one or more note ids ("N3", "N1, N2", "N3 and N7").
CITATION = re.compile(r"thesis-notes\.md((?:(?:,\s*|\s+and\s+|\s+)N\d+\b)+)")
HEADING = re.compile(r"^## (N\d+) ", re.MULTILINE)
OUTSIDE = re.compile(r"errata", re.IGNORECASE)
THIS_FILE = "tests/test_thesis_notes.py"


def cited_notes(text: str) -> list[str]:
    return [n for m in CITATION.finditer(text) for n in re.findall(r"N\d+", m.group(1))]


def tree_texts() -> dict[str, str]:
    """Every text file of the working tree that git tracks or would track, by relative path."""
    names = subprocess.run(["git", "ls-files", "--cached", "--others", "--exclude-standard", "-z"],
                           cwd=ROOT, check=True, capture_output=True).stdout.decode().split("\0")
    texts = {}
    for name in filter(None, names):
        path = ROOT / name
        if not path.is_file():  # deleted in the working tree
            continue
        try:
            texts[name] = path.read_text(encoding="utf-8")
        except UnicodeDecodeError:  # images and other binaries
            continue
    return texts


def note_ids() -> list[str]:
    return HEADING.findall(NOTES.read_text(encoding="utf-8"))


def test_citation_pattern_reads_every_form_used():
    text = ("(docs/thesis-notes.md N3) ... thesis-notes.md N1, N2: ... (docs/thesis-notes.md N3 and N7)"
            " ... `docs/thesis-notes.md N<k>` ... thesis-notes.md N12.")
    assert cited_notes(text) == ["N3", "N1", "N2", "N3", "N7", "N12"]
    assert OUTSIDE.search("see ERRATA 3") and OUTSIDE.search("the reduction of errata note 1")


def test_notes_are_numbered_once_and_in_order():
    ids = note_ids()
    assert ids == [f"N{k}" for k in range(1, len(ids) + 1)]


def test_every_cited_note_exists():
    ids = set(note_ids())
    texts = tree_texts()
    missing = {(name, n) for name, text in texts.items() for n in cited_notes(text) if n not in ids}
    assert not missing, f"citations of notes that docs/thesis-notes.md does not have: {sorted(missing)}"
    # the notes' references to each other ("(N4)", "N1, N2") too
    inner = set(re.findall(r"\bN\d+\b", NOTES.read_text(encoding="utf-8")))
    assert inner <= ids, f"docs/thesis-notes.md refers to notes it does not have: {sorted(inner - ids)}"
    assert "device/model/safety.py" in texts and "N1" in cited_notes(texts["device/model/safety.py"])


def test_no_citation_points_outside_the_repository():
    found = [f"{name}:{text.count(chr(10), 0, m.start()) + 1}: {m.group(0)}"
             for name, text in tree_texts().items()
             if name != THIS_FILE
             for m in OUTSIDE.finditer(text)]
    assert not found, "cite docs/thesis-notes.md N<k> instead of the reading notes: " + "; ".join(found)

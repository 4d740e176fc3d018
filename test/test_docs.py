"""The docs name tests that exist: every ``test/...py::name`` in README.md and docs/*.md.

docs/theory.md's guarantee table says, for each assumption, which test shows it; a test that
was renamed or moved leaves the table pointing at nothing, and a newcomer cannot tell whether
the assumption is still shown. A ``::name`` with no file before it in the same line refers to
the file named last on that line.
"""
import ast
import re
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
REF = re.compile(r"(test/[\w/]+\.py)?((?:::\w+)+)|(test/[\w/]+\.py)")


def _names(path: Path) -> set[str]:
    """``name`` and ``Class::method`` for the test functions and classes of a module."""
    tree = ast.parse(path.read_text())
    out = set()
    for node in tree.body:
        if isinstance(node, (ast.FunctionDef, ast.AsyncFunctionDef)):
            out.add(node.name)
        elif isinstance(node, ast.ClassDef):
            out.add(node.name)
            out.update(f"{node.name}::{f.name}" for f in node.body
                       if isinstance(f, (ast.FunctionDef, ast.AsyncFunctionDef)))
    return out


def references(text: str):
    """``(line number, file, name or None)`` for each test reference in ``text``."""
    for n, line in enumerate(text.splitlines(), 1):
        current = None
        for m in REF.finditer(line):
            if m.group(3):
                current = m.group(3)
                yield n, current, None
                continue
            if m.group(1):
                current = m.group(1)
            if current is not None:
                yield n, current, m.group(2)[2:]


def test_every_test_named_in_the_docs_exists():
    docs = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    missing, seen = [], 0
    for doc in docs:
        for n, file, name in references(doc.read_text()):
            seen += 1
            path = REPO / file
            if not path.is_file():
                missing.append(f"{doc.name}:{n}: {file} does not exist")
            elif name is not None and name not in _names(path):
                missing.append(f"{doc.name}:{n}: {file}::{name} does not exist")
    assert seen > 20          # the docs do name tests (the pattern still matches them)
    assert not missing, "\n".join(missing)


def test_references_follow_the_last_file_on_the_line():
    refs = list(references("`test/a/test_x.py::test_one`, `::test_two`; `test/b.py`"))
    assert refs == [(1, "test/a/test_x.py", "test_one"), (1, "test/a/test_x.py", "test_two"),
                    (1, "test/b.py", None)]

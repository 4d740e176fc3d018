"""The docs name tests that exist: every ``test/...py::name`` in README.md and docs/*.md.

docs/theory.md's guarantee table says, for each assumption, which test shows it; a test that
was renamed or moved leaves the table pointing at nothing, and a newcomer cannot tell whether
the assumption is still shown. A ``::name`` with no file before it in the same line refers to
the file named last on that line.
"""
import ast
import re
from pathlib import Path

import pytest

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


@pytest.mark.slow
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


LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")


def _slug(heading: str) -> str:
    """GitHub's anchor of a Markdown heading: lower case, punctuation dropped, spaces to '-'."""
    text = re.sub(r"[`*_]|<[^>]+>", "", heading.strip().lower())
    return re.sub(r"[^\w\- ]", "", text).replace(" ", "-")


def _anchors(path: Path) -> set[str]:
    out = set()
    fenced = False
    for line in path.read_text().splitlines():
        if line.lstrip().startswith("```"):
            fenced = not fenced
        elif not fenced and line.startswith("#"):
            base = _slug(line.lstrip("#"))
            n, slug = 0, base
            while slug in out:           # repeated headings get -1, -2, ...
                n += 1
                slug = f"{base}-{n}"
            out.add(slug)
    return out


def relative_links(text: str):
    """``(line number, target)`` of each relative link (no scheme, not mailto) outside code fences."""
    fenced = False
    for n, line in enumerate(text.splitlines(), 1):
        if line.lstrip().startswith("```"):
            fenced = not fenced
            continue
        if fenced:
            continue
        for m in LINK.finditer(line):
            target = m.group(1)
            if not re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):
                yield n, target


def test_every_relative_link_in_the_docs_resolves_in_a_clone():
    """A link in README.md or docs/*.md to a file of the repository (and to a heading of a
    Markdown file) points at something that exists in a clone: the old README linked files
    that are not in the repository."""
    docs = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
    broken, seen = [], 0
    for doc in docs:
        for n, target in relative_links(doc.read_text()):
            seen += 1
            path_part, _, anchor = target.partition("#")
            path = (doc.parent / path_part).resolve() if path_part else doc
            if not path.exists():
                broken.append(f"{doc.name}:{n}: {target}: no such file")
            elif REPO not in path.parents and path != REPO:
                broken.append(f"{doc.name}:{n}: {target}: outside the repository")
            elif anchor and path.suffix == ".md" and anchor not in _anchors(path):
                broken.append(f"{doc.name}:{n}: {target}: no heading #{anchor} in {path.name}")
    assert seen > 5          # the docs do link files (the pattern still matches them)
    assert not broken, "\n".join(broken)


#: files named in the docs that are not in a clone on purpose: the campaign history's old module name
NOT_IN_A_CLONE = {"reachset_ros/nodes/campaign_driver.py"}


def test_every_file_path_named_in_the_docs_is_in_a_clone():
    """README.md and docs/*.md name files as `dir/file.ext` (a top-level directory of the
    repository) and must not name files outside the repository (``/work/...``): a reader of a
    clone cannot open them. docs/performance.md named a note of the development machine."""
    tops = [p.name for p in REPO.iterdir() if p.is_dir() and not p.name.startswith(".")]
    named = re.compile(r"`((?:%s)/[\w./-]*\.\w+)(?:::\w+)*`" % "|".join(map(re.escape, tops)))
    missing, seen = [], 0
    for doc in [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]:
        for n, line in enumerate(doc.read_text().splitlines(), 1):
            for m in named.finditer(line):
                seen += 1
                if m.group(1) not in NOT_IN_A_CLONE and not (REPO / m.group(1)).exists():
                    missing.append(f"{doc.name}:{n}: {m.group(1)}")
            missing += [f"{doc.name}:{n}: {m.group(0)} is outside the repository"
                        for m in re.finditer(r"(?<![\w.])/work/[\w./-]+", line)]
    assert seen > 20
    assert not missing, "\n".join(missing)


def test_relative_links_and_anchors():
    text = "[a](docs/x.md#two-words) ![i](img.png) [w](https://x.org) `[c](no.md)`\n```\n[f](fenced.md)\n```"
    assert list(relative_links(text)) == [(1, "docs/x.md#two-words"), (1, "img.png"), (1, "no.md")]
    assert _slug("Two `words`, here!") == "two-words-here"

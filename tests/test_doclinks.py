"""Every relative link of the documentation leads somewhere: a file of the repository, and a heading of it when it
names one.  README.md, CONTRIBUTING.md and docs/*.md link into each other by path and GitHub anchor; a section
moved or renamed would otherwise leave a dead link that nothing notices.
"""

from __future__ import annotations

import glob
import os
import re

import pytest
from conftest import REPO

DOCS = sorted([os.path.join(REPO, "README.md"), os.path.join(REPO, "CONTRIBUTING.md"), *glob.glob(os.path.join(REPO, "docs", "*.md"))])
# [text](target) outside code: a target with no scheme (http:, mailto:) is relative
_LINK = re.compile(r"(?<!\\)\]\(([^)\s]+)\)")
_FENCE = re.compile(r"^([ \t]*)(```|~~~).*?^\1\2[ \t]*$", re.M | re.S)
_CODE = re.compile(r"(`+)(?!`).*?(?<!`)\1(?!`)", re.S)


def slug(heading: str) -> str:
    """GitHub's anchor for a heading: lower case, code marks and punctuation but `-` and `_` dropped, spaces to `-`."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading.strip())  # a link in a heading: its text
    return re.sub(r"[^\w\- ]", "", text.lower()).replace(" ", "-")


def anchors(text: str) -> set[str]:
    """Every anchor GitHub makes for the headings of a markdown text (a repeated one gets -1, -2, ...)."""
    seen: dict[str, int] = {}
    found = set()
    for heading in re.findall(r"^#{1,6} (.*?)[ \t]*#*[ \t]*$", _FENCE.sub("", text), re.M):
        base = slug(heading)
        count = seen.get(base, 0)
        found.add(base if count == 0 else f"{base}-{count}")
        seen[base] = count + 1
    return found


def relative_links(text: str) -> list[tuple[int, str]]:
    """Each relative link target of a markdown text, with its line, leaving out code blocks and code spans."""
    prose = _FENCE.sub(lambda m: "\n" * m.group(0).count("\n"), text)
    prose = _CODE.sub(lambda m: re.sub(r"[^\n]", " ", m.group(0)), prose)
    links = []
    for match in _LINK.finditer(prose):
        target = match.group(1)
        if not re.match(r"[a-z][a-z0-9+.-]*:", target, re.I):
            links.append((prose.count("\n", 0, match.start()) + 1, target))
    return links


def dead_links(path: str) -> list[str]:
    """The relative links of the file at `path` that lead to no file, or to no heading of it."""
    with open(path, encoding="utf-8") as handle:
        text = handle.read()
    dead = []
    for line, target in relative_links(text):
        file, _, anchor = target.partition("#")
        where = os.path.normpath(os.path.join(os.path.dirname(path), file)) if file else path
        name = f"{os.path.relpath(path, REPO)}:{line}: {target}"
        if not os.path.exists(where):
            dead.append(f"{name}: no such file")
        elif anchor and where.endswith(".md"):
            with open(where, encoding="utf-8") as handle:
                if anchor not in anchors(handle.read()):
                    dead.append(f"{name}: no heading #{anchor} in {os.path.relpath(where, REPO)}")
    return dead


def test_the_documentation_files_are_found():
    names = {os.path.relpath(p, REPO) for p in DOCS}
    assert {"README.md", "CONTRIBUTING.md", "docs/scenarios.md", "docs/permissions.md", "docs/nightly.md"} <= names, names
    assert all(os.path.exists(p) for p in DOCS)


@pytest.mark.parametrize("path", DOCS, ids=lambda p: os.path.relpath(p, REPO))
def test_every_relative_link_leads_to_a_file_and_heading(path):
    dead = dead_links(path)
    assert not dead, "\n".join(dead)


def test_a_dead_link_is_found_and_code_is_not_read_as_links(tmp_path):
    (tmp_path / "other.md").write_text("# A title: `code`, and more\n\n## Twice\n\n## Twice\n", encoding="utf-8")
    doc = tmp_path / "doc.md"
    doc.write_text(
        "# Here\n\n[ok](other.md#a-title-code-and-more) [ok](other.md#twice-1) [ok](#here) [web](https://example.com/x)\n"
        "[gone](missing.md) [no heading](other.md#nowhere) `[code](missing.md)`\n\n```md\n[block](missing.md)\n```\n",
        encoding="utf-8",
    )
    dead = [line.split(": ", 1)[1] for line in dead_links(str(doc))]
    other = os.path.relpath(str(tmp_path / "other.md"), REPO)
    assert dead == ["missing.md: no such file", f"other.md#nowhere: no heading #nowhere in {other}"]

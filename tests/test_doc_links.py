"""The README stays short and every relative link in it and in docs/ points to a file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parents[1]
PAGES = [REPO / "README.md", *sorted((REPO / "docs").glob("*.md"))]
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.S | re.M)


def relative_links(text: str) -> list[str]:
    """Targets of Markdown links and images outside code blocks, without their ``#anchor``;
    absolute URLs and in-page anchors left out.

    >>> relative_links("[a](x.md#y) ![b](r.png) [c](https://e.org) [d](#z)\\n```\\n[e](f)\\n```")
    ['x.md', 'r.png']
    """
    text = FENCE.sub("", text)
    out = []
    for target in LINK.findall(text):
        if re.match(r"^([a-z]+:|#)", target):
            continue
        out.append(target.split("#", 1)[0])
    return out


def test_readme_is_at_most_250_lines() -> None:
    assert len((REPO / "README.md").read_text().splitlines()) <= 250


@pytest.mark.parametrize("page", PAGES, ids=lambda p: p.name)
def test_every_relative_link_resolves(page: Path) -> None:
    missing = [t for t in relative_links(page.read_text()) if not (page.parent / t).exists()]
    assert missing == []


def test_every_docs_page_is_linked_from_the_readme() -> None:
    linked = {(REPO / t).resolve() for t in relative_links((REPO / "README.md").read_text())}
    assert [p.name for p in PAGES[1:] if p.resolve() not in linked] == []


def test_a_broken_link_is_caught(tmp_path: Path) -> None:
    page = tmp_path / "p.md"
    page.write_text("[x](nowhere.md)")
    with pytest.raises(AssertionError):
        test_every_relative_link_resolves(page)

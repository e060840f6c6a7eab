"""Every relative link of README.md and docs/*.md resolves: the file (or folder) exists, and an
anchor into a Markdown page names one of its headings (GitHub's slugs)."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

ROOT = Path(__file__).parents[1]
PAGES = [ROOT / "README.md", *sorted((ROOT / "docs").glob("*.md"))]
# [text](target) and ![alt](target); a target ends at whitespace or the closing parenthesis.
LINK = re.compile(r"!?\[[^\]]*\]\(([^)\s]+)(?:\s+\"[^\"]*\")?\)")
FENCE = re.compile(r"^```.*?^```", re.MULTILINE | re.DOTALL)


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, spaces to hyphens."""
    text = re.sub(r"[`*_]|\$", "", heading.strip().lower())
    return "".join(c for c in text if c.isalnum() or c in " -_").replace(" ", "-")


def anchors(page: Path) -> set[str]:
    text = FENCE.sub("", page.read_text())
    return {slug(m.group(1)) for m in re.finditer(r"^#+\s+(.*)$", text, re.MULTILINE)}


def links(page: Path) -> list[str]:
    return [m.group(1) for m in LINK.finditer(FENCE.sub("", page.read_text()))]


@pytest.mark.parametrize("page", PAGES, ids=lambda p: str(p.relative_to(ROOT)))
def test_every_relative_link_resolves(page):
    broken = []
    for target in links(page):
        if re.match(r"^[a-z]+:", target):  # http:, https:, mailto:
            continue
        path, _, anchor = target.partition("#")
        resolved = (page.parent / path).resolve() if path else page
        if not resolved.exists():
            broken.append(f"{target}: no {resolved}")
        elif anchor and resolved.suffix == ".md" and anchor not in anchors(resolved):
            broken.append(f"{target}: no heading #{anchor} in {resolved.name}")
    assert not broken, "\n".join(broken)


def test_the_pages_have_links():
    assert len(links(ROOT / "README.md")) >= 10


def test_the_pages_a_new_user_reads_say_how_to_choose_p2():
    """P2 is the element for a thin part that bends (P1 locks): the tutorial and the geometry
    page name the case key and the --set that select it, and both are what the schema takes."""
    from harness.scene.schema import SCHEMA
    from harness.scene.scene import apply_override

    key = SCHEMA["scene"]["element"]
    assert key.default == "P1" and key.check("P2") is None and key.check("P3") is not None
    raw: dict = {}
    apply_override(raw, "scene.element=P2")
    assert raw == {"scene": {"element": "P2"}}
    for page in ("tutorial.md", "geometry.md"):
        text = (ROOT / "docs" / page).read_text()
        assert 'element = "P2"' in text and "--set scene.element=P2" in text, page
        assert "harness/scene/schema.py" in text and "lock" in text, page  # where the key lives, and why P2

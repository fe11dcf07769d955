"""Links of the documentation resolve: every relative link and anchor in README.md, CHANGELOG.md and docs/**, and
every ``docs/<page>.md, "<Section>"`` citation in the code and the tests names a page with a heading that contains
that text. Reads text files only (well under a second); ``python tests/test_docs_links.py`` prints what it finds.
"""
from __future__ import annotations

import re
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]

_FENCE = re.compile(r"^(```|~~~)")
_HEADING = re.compile(r"^(#{1,6})\s+(.*?)\s*#*\s*$")
# [text](target) and ![alt](target); the target has no spaces (titles are not used in these pages).
_LINK = re.compile(r"!?\[(?:[^\]\[]|\[[^\]]*\])*\]\(([^)\s]+)\)")
_CODE_SPAN = re.compile(r"`[^`\n]*`")
# docs/<page>.md, then an optional comma or bracket and whitespace (a docstring's or comment's line break
# included), then the section in double quotes or in reStructuredText's double backticks.
_CITATION = re.compile(r"(docs/[\w/.-]+?\.md)\s*[,(]?[\s#]*(?:\"([^\"\n]+)\"|``([^`\n]+)``)")


def doc_files() -> list[Path]:
    return [ROOT / "README.md", ROOT / "CHANGELOG.md", *sorted((ROOT / "docs").rglob("*.md"))]


def _prose_lines(text: str) -> list[tuple[int, str]]:
    """(line number, line) outside fenced code blocks."""
    out, fenced = [], False
    for i, line in enumerate(text.splitlines(), 1):
        if _FENCE.match(line.lstrip()):
            fenced = not fenced
            continue
        if not fenced:
            out.append((i, line))
    return out


def slug(heading: str) -> str:
    """GitHub's anchor of a heading: lower case, punctuation dropped, each space a hyphen."""
    text = re.sub(r"\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # a link in a heading anchors on its text
    text = re.sub(r"[^\w\- ]", "", text.lower())
    return text.replace(" ", "-")


def headings(path: Path) -> list[str]:
    return [m.group(2) for _, line in _prose_lines(path.read_text()) if (m := _HEADING.match(line))]


def anchors(path: Path) -> set[str]:
    """Every anchor of a Markdown file, with GitHub's -1, -2, ... for repeated headings."""
    seen: dict[str, int] = {}
    out = set()
    for h in headings(path):
        s = slug(h)
        n = seen.get(s, 0)
        seen[s] = n + 1
        out.add(s if n == 0 else f"{s}-{n}")
    return out


def broken_links() -> list[str]:
    """'file:line: target (why)' for every relative link or anchor that does not resolve."""
    bad = []
    cache: dict[Path, set[str]] = {}
    for f in doc_files():
        for i, line in _prose_lines(f.read_text()):
            for m in _LINK.finditer(_CODE_SPAN.sub("", line)):
                target = m.group(1)
                if re.match(r"[a-z][a-z0-9+.-]*:", target):  # http:, https:, mailto:
                    continue
                path_part, _, anchor = target.partition("#")
                dest = (f.parent / path_part).resolve() if path_part else f
                where = f"{f.relative_to(ROOT)}:{i}: {target}"
                if not dest.exists():
                    bad.append(f"{where} (no such file)")
                elif anchor:
                    if dest.suffix != ".md":
                        bad.append(f"{where} (anchor into a file that is not Markdown)")
                    elif anchor not in cache.setdefault(dest, anchors(dest)):
                        bad.append(f"{where} (no such heading)")
    return bad


def _norm(text: str) -> str:
    return re.sub(r"\s+", " ", text.replace("`", "").replace("\u2019", "'")).strip().lower()


def broken_citations() -> list[str]:
    """'file:line: docs/page.md, "Section" (why)' for every citation whose page or heading is missing."""
    bad = []
    files = sorted(p for d in ("pipeline", "stucco_cli", "tests") for p in (ROOT / d).rglob("*.py")
                   if p != Path(__file__).resolve())  # this file's examples are not citations
    for f in files:
        text = f.read_text()
        for m in _CITATION.finditer(text):
            page, section = m.group(1), m.group(2) or m.group(3)
            line = text.count("\n", 0, m.start()) + 1
            where = f"{f.relative_to(ROOT)}:{line}: {page}, \"{section}\""
            dest = ROOT / page
            if not dest.exists():
                bad.append(f"{where} (no such page)")
            elif not any(_norm(section) in _norm(h) for h in headings(dest)):
                bad.append(f"{where} (no heading contains it)")
    return bad


def test_slug_follows_github():
    assert slug("The estimators' own randomness: `--estimator-stream`") == \
        "the-estimators-own-randomness---estimator-stream"
    assert slug("Where grasps are lost: `stucco bench retrieval`") == "where-grasps-are-lost-stucco-bench-retrieval"
    assert slug("`sim_run`") == "sim_run"


def test_the_citation_pattern_reads_both_quotings_and_line_breaks():
    text = 'see docs/a.md, "One"; docs/b.md,\n    # "Two" and docs/c.md, ``three``'
    assert [(m.group(1), m.group(2) or m.group(3)) for m in _CITATION.finditer(text)] == \
        [("docs/a.md", "One"), ("docs/b.md", "Two"), ("docs/c.md", "three")]


def test_every_relative_link_and_anchor_of_the_docs_resolves():
    bad = broken_links()
    assert not bad, "broken links:\n" + "\n".join(bad)


def test_every_docs_citation_in_the_code_names_an_existing_heading():
    bad = broken_citations()
    assert not bad, "citations of missing sections:\n" + "\n".join(bad)


if __name__ == "__main__":
    found = broken_links() + broken_citations()
    print("\n".join(found) or "all links, anchors and citations resolve")

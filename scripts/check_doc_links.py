#!/usr/bin/env python3
"""Check the relative links of the project's markdown (docs/, README.md, ARCHITECTURE.md).

Every `[text](target)`, `![alt](target)` and `[label]: target` whose target is
not a URL must name an existing file or folder (relative to the page), and a
`#anchor` into a markdown page must match one of its headings as GitHub
renders them (lower case, punctuation dropped, spaces to hyphens, repeats
suffixed -1, -2, ...) or an explicit `id=`/`name=` anchor. Links inside code
(fenced blocks and `inline code`) are not links. Prints one line per broken
link (file:line: target: reason) and exits 1 if there is any.

Usage: python3 scripts/check_doc_links.py [ROOT]   (default: the repository)
"""
import re
import sys
import unicodedata
from pathlib import Path

INLINE = re.compile(r"!?\[(?:[^\[\]]|\[[^\]]*\])*\]\(\s*<?([^)\s>]+)>?(?:\s+\"[^\"]*\")?\s*\)")
REFDEF = re.compile(r"^\s{0,3}\[[^\]]+\]:\s+<?(\S+?)>?(?:\s+.*)?$")
HEADING = re.compile(r"^\s{0,3}#{1,6}\s+(.*?)\s*#*\s*$")
HTML_ID = re.compile(r"""<[^>]+\b(?:id|name)=["']([^"']+)["']""")
EXTERNAL = re.compile(r"^(?:[a-z][a-z0-9+.-]*:|//)", re.I)


def lines_outside_code(text):
    """(line number, line with inline code removed) for lines outside fences."""
    fence = None
    for number, line in enumerate(text.split("\n"), 1):
        marker = re.match(r"^\s{0,3}(`{3,}|~{3,})", line)
        if marker:
            if fence is None:
                fence = marker.group(1)[0] * 3
            elif marker.group(1).startswith(fence):
                fence = None
            continue
        if fence is None:
            yield number, re.sub(r"(`+).*?\1", "", line)


def slug(heading):
    """GitHub's anchor for a heading's text (github-slugger's rule)."""
    text = re.sub(r"!?\[([^\]]*)\]\([^)]*\)", r"\1", heading)  # links -> their text
    text = re.sub(r"<[^>]+>", "", text).replace("`", "").lower()
    kept = (c for c in text if c.isalnum() or c in " -_" or unicodedata.category(c).startswith("M"))
    return "".join(kept).replace(" ", "-")


def anchors(path, cache={}):
    if path not in cache:
        found, seen = set(), {}
        text = path.read_text(encoding="utf-8")
        for _, line in lines_outside_code(text):
            found.update(HTML_ID.findall(line))
        fence = False
        for line in text.split("\n"):
            if re.match(r"^\s{0,3}(`{3,}|~{3,})", line):
                fence = not fence
            heading = None if fence else HEADING.match(line)
            if heading:
                base = slug(heading.group(1))
                count = seen.get(base, 0)
                seen[base] = count + 1
                found.add(base if count == 0 else f"{base}-{count}")
        cache[path] = found
    return cache[path]


def check(page, root):
    problems = []
    lines = dict(lines_outside_code(page.read_text(encoding="utf-8")))
    found = [(n, ref.group(1)) for n, line in lines.items() if (ref := REFDEF.match(line))]
    # A link's text may wrap: search the prose with code blanked, line by line
    # number kept (code lines become empty).
    prose = "\n".join(lines.get(n, "") for n in range(1, max(lines, default=0) + 1))
    for match in INLINE.finditer(prose):
        found.append((prose.count("\n", 0, match.start(1)) + 1, match.group(1)))
    for number, target in sorted(found):
        if EXTERNAL.match(target):
            continue
        file_part, _, anchor = target.partition("#")
        dest = (page.parent / file_part).resolve() if file_part else page
        where = f"{page.relative_to(root)}:{number}: {target}"
        if not dest.exists():
            problems.append(f"{where}: no such file")
        elif anchor and dest.suffix == ".md" and anchor not in anchors(dest):
            problems.append(f"{where}: no heading with anchor #{anchor}")
    return problems


def main():
    root = Path(sys.argv[1] if len(sys.argv) > 1 else Path(__file__).resolve().parent.parent)
    pages = sorted(root.glob("docs/**/*.md")) + [root / "README.md", root / "ARCHITECTURE.md"]
    problems = [p for page in pages if page.exists() for p in check(page, root)]
    for problem in problems:
        print(problem)
    print(f"check_doc_links: {len(pages)} pages, {len(problems)} broken links")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main())

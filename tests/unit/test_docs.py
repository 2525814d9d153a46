#!/usr/bin/env python3
"""The documents hold together: every relative link of README.md and docs/ resolves; the pages a
user reads (README.md, docs/guides/, docs/results/) stay short (README at most 150 lines, a page at
most 300) and cite no commit hash; and every figure in a results page's tables is in a data file the
page links to (its per-seed results), so a table cannot drift from what was measured.
The history of how figures were reached is in docs/record/, which only the link check covers.

  tests/unit/test_docs.py SOURCE_DIR
"""
import re
import sys
from pathlib import Path

LINK = re.compile(r"\]\(([^)\s]+)\)")
HASH = re.compile(r"(?<![\w./-])(?=[0-9a-f]*[a-f])(?=[0-9a-f]*[0-9])[0-9a-f]{7,40}(?![\w-])")
# A figure in a table may group thousands ("3,390,800"); a data file's numbers are plain (CSV).
FIGURE = re.compile(r"(?<![\w.])[-+]?(?:\d{1,3}(?:,\d{3})+|\d+)(?:\.\d+)?")
NUMBER = re.compile(r"[-+]?\d+(?:\.\d+)?(?:[eE][-+]?\d+)?")


def pages(src):
    return [src / "README.md"] + sorted((src / "docs").rglob("*.md"))


def user_pages(src):
    return [src / "README.md"] + sorted((src / "docs" / "guides").glob("*.md")) + sorted(
        (src / "docs" / "results").glob("*.md"))


def outside_code(text):
    """The text without fenced code blocks (commands and program output may hold anything)."""
    return re.sub(r"```.*?```", "", text, flags=re.S)


def check_links(src, fails):
    for page in pages(src):
        for target in LINK.findall(outside_code(page.read_text())):
            if re.match(r"[a-z]+:", target) or target.startswith("#"):
                continue
            path = (page.parent / target.split("#")[0]).resolve()
            if not path.exists():
                fails.append(f"{page.relative_to(src)}: link to {target} does not resolve")


def check_user_pages(src, fails):
    for page in user_pages(src):
        text = page.read_text()
        lines = text.count("\n")
        most = 150 if page.name == "README.md" else 300
        if lines > most:
            fails.append(f"{page.relative_to(src)}: {lines} lines, more than {most}")
        for h in HASH.findall(outside_code(text)):
            fails.append(f"{page.relative_to(src)}: cites what looks like a commit hash ({h})")


def table_figures(text):
    for line in outside_code(text).splitlines():
        if not line.startswith("|") or re.match(r"\|\s*-", line):
            continue
        cells = [c.strip() for c in line.strip("|").split("|")]
        for cell in cells[1:]:  # the first cell names the row (a seed, a robot)
            for n in FIGURE.findall(re.sub(r"\[[^\]]*\]\([^)]*\)", "", cell)):
                yield n.replace(",", "").lstrip("+")


def check_results(src, fails):
    for page in sorted((src / "docs" / "results").glob("*.md")):
        text = page.read_text()
        data = [(page.parent / t.split("#")[0]).resolve() for t in LINK.findall(text)]
        data = [d for d in data if d.is_file() and "data" in d.parts]
        if not data:
            fails.append(f"{page.relative_to(src)}: names no data file (a link into docs/data/)")
            continue
        tokens = set()
        for d in data:
            for n in NUMBER.findall(d.read_text(errors="replace")):
                tokens.add(n.lstrip("+"))
        for n in table_figures(text):
            if n not in tokens:
                fails.append(f"{page.relative_to(src)}: table figure {n} is in none of its data files")


def check_readme_figures(src, fails):
    """Every figure in the "per seed" and "time" columns of the README's results table is a table
    entry of the results page its row links."""
    for line in outside_code((src / "README.md").read_text()).splitlines():
        target = re.search(r"\]\((docs/results/[^)#]+)\)", line)
        if not line.startswith("|") or not target:
            continue
        page = src / target.group(1)
        if not page.is_file():
            continue  # the link check names it
        known = set(table_figures(page.read_text()))
        cells = line.strip("|").split("|")
        if len(cells) < 5:
            continue
        for n in table_figures("| x |" + cells[3] + "|" + cells[4] + "|"):
            if n not in known:
                fails.append(f"README.md: figure {n} of the {page.stem} row is in no table of {target.group(1)}")


def main():
    src = Path(sys.argv[1]).resolve()
    fails = []
    check_links(src, fails)
    check_user_pages(src, fails)
    check_results(src, fails)
    check_readme_figures(src, fails)
    for f in fails:
        print("FAIL: " + f)
    if not fails:
        print(f"PASS: {len(pages(src))} pages, {len(user_pages(src))} for users")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())

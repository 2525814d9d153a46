#!/usr/bin/env python3
"""The documents hold together: every relative link of README.md and docs/ resolves; the pages a
user reads (README.md, docs/guides/, docs/results/) stay short (README at most 150 lines, a page at
most 300) and cite no commit hash; and every figure in a results page's table is in the row for
that seed (or label) of the data files linked before the table, so a table cannot drift from what
was measured. A column whose header names a row of a seed's data file ("plain-dry") is matched to
that row; other columns only to the seed's row or file, so a figure moved between two of them
passes. A self-test edits the pages in memory
(figures given to the wrong seed) and fails if the results check lets such an edit through.
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




def letters(text):
    return re.sub(r"[^a-z]", "", text.lower())


def row_key(label):
    """A table row's key: (seed, name, label). "2", "seed 2" and "Honey Badger, seed 2, 15 workers"
    give seed 2 (the last with the name "honeybadger"); a row without a seed ("median") its label."""
    label = label.strip()
    m = re.search(r"^(\d+)$|\bseed\s*(\d+)\b", label, re.I)
    seed = int(m.group(1) or m.group(2)) if m else None
    head = label.split(",")[0]
    name = letters(head) if seed is not None and "," in label and not re.search(r"\d", head) else ""
    return seed, name, letters(label)


def table_blocks(text):
    """Each table of a text (outside code) with the text before it: (prose, header, rows), a row
    being (label, cells)."""
    blocks, prose, table = [], [], []

    def close():
        if table:
            sep = next((i for i, l in enumerate(table) if re.match(r"\|\s*:?-", l)), None)
            cells = [[c.strip() for c in l.strip().strip("|").split("|")] for l in table]
            header = cells[sep - 1] if sep else None
            rows = [c for i, c in enumerate(cells) if sep is None or i > sep]
            blocks.append(("\n".join(prose), header, [(r[0], r[1:]) for r in rows]))
            prose.clear()
            table.clear()

    for line in outside_code(text).splitlines():
        if line.startswith("|"):
            table.append(line)
        else:
            close()
            prose.append(line)
    close()
    return blocks


def cell_figures(cell):
    for n in FIGURE.findall(re.sub(r"\[[^\]]*\]\([^)]*\)", "", cell)):
        yield n.replace(",", "").lstrip("+")


def numbers(text):
    return {n.lstrip("+") for n in NUMBER.findall(text)}


def data_records(path):
    """What a data file holds, row by row: (seed, label, context, numbers). A file whose name
    carries a seed ("_seed2_") is one run's and one record; a CSV with a seed column, a row each; a
    markdown table, a row each, its context the section it is in ("== seed 2", "## hexapod_s2");
    any other file is one record with no seed."""
    text = path.read_text(errors="replace")
    m = re.search(r"seed(\d+)", path.name)
    lines = text.splitlines()
    if m:
        # the whole file, and its table rows by their label ("plain-dry") for a page's columns
        seed = int(m.group(1))
        return [(seed, "", letters(path.name), numbers(text))] + [
            (seed, letters(c[0]), letters(path.name), numbers("|".join(c[1:])))
            for c in ([x.strip() for x in l.strip().strip("|").split("|")] for l in lines
                      if l.startswith("|") and not re.match(r"\|\s*:?-", l)) if letters(c[0])]
    if path.suffix == ".csv" and lines and lines[0].split(",")[0].strip() == "seed":
        return [(int(float(l.split(",")[0])), "", letters(path.name), numbers(l))
                for l in lines[1:] if l.strip()]
    records, heading, run, last = [], "", "", ""
    for line in lines:
        if line.startswith("=="):
            run = line
        elif line.startswith("#"):
            # a "##" heading stands alone; "#" comment lines before a block are read together
            heading = heading + line if last.startswith("#") and not line.startswith("##") else line
            run = ""
        elif line.startswith("|") and not re.match(r"\|\s*:?-", line):
            cells = [c.strip() for c in line.strip().strip("|").split("|")]
            seed, _, label = row_key(cells[0])
            records.append((seed, label, letters(path.name + heading + run), numbers("|".join(cells[1:]))))
        last = line
    return records or [(None, "", letters(path.name), numbers(text))]


def row_numbers(key, records):
    """The numbers of the data rows for a table row: those of its seed (or label), of the robot
    it names; one-run files without a seed stand for any seed of what they name."""
    seed, name, label = key
    named = [r for r in records if name in r[2]]
    if seed is None:
        match = [r for r in named if r[0] is None and r[1] == label]
    else:
        match = [r for r in named if r[0] == seed] or [r for r in named if r[0] is None and not r[1]]
    if not match:
        return None
    return set().union(*(r[3] for r in match))


def check_results(src, fails):
    """Each figure of a results table is in the row of its data for that seed (or label, "median"):
    the data being the data files the text before the table links (or the table before's)."""
    for page in sorted((src / "docs" / "results").glob("*.md")):
        check_results_page(src, page, page.read_text(), fails)


def check_results_page(src, page, text, fails):
    where = page.relative_to(src)
    if not any("data" in (page.parent / t.split("#")[0]).resolve().parts for t in LINK.findall(text)):
        fails.append(f"{where}: names no data file (a link into docs/data/)")
    data = []
    for prose, header, rows in table_blocks(text):
        linked = [(page.parent / t.split("#")[0]).resolve() for t in LINK.findall(prose)]
        linked = [d for d in linked if d.is_file() and "data" in d.parts]
        data = linked or data
        if not data:
            fails.append(f"{where}: a table before any link into docs/data/ ({rows[0][0] if rows else header})")
            continue
        records = [r for d in data for r in data_records(d)]
        everything = set().union(*(r[3] for r in records))
        for n in (f for c in (header or [])[1:] for f in cell_figures(c)):
            if n not in everything:
                fails.append(f"{where}: header figure {n} is in none of its data files")
        columns = [letters(h) for h in (header or [])[1:]]
        for label, cells in rows:
            key = row_key(label)
            known = row_numbers(key, records)
            if known is None:
                fails.append(f"{where}: row '{label}' has no row for it in "
                             + ", ".join(d.name for d in data))
                continue
            for i, c in enumerate(cells):
                # a column named as a row of the seed's file ("plain-dry"): that row's figures
                column = [r[3] for r in records if key[0] is not None and r[0] == key[0] and i < len(columns)
                          and columns[i] and r[1] == columns[i]]
                here = set().union(*column) if column else known
                for n in cell_figures(c):
                    if n not in here:
                        fails.append(f"{where}: row '{label}': figure {n} is not in its data row"
                                     + (f" for '{header[i + 1]}'" if column else "") + " ("
                                     + ", ".join(d.name for d in data) + ")")


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


def self_test(src, fails):
    """The results check catches a figure changed to one its data files hold for another seed (in
    the Jetbot and mCLARI tables), and each table's rows given to another seed."""
    results = src / "docs" / "results"
    edits = [("jetbot.md", "| 1 | 24 | 1241200 | 20 | 99 |", "| 1 | 24 | 1241200 | 20 | 96 |"),
             ("mclari.md", "| 2 | 1500 | 153440 | 611769 | 94 |", "| 2 | 1500 | 153440 | 611769 | 90 |")]
    for name, before, after in edits:
        text = (results / name).read_text()
        if before not in text:
            fails.append(f"self-test: docs/results/{name} no longer holds '{before}'; name another edit")
            continue
        caught = []
        check_results_page(src, results / name, text.replace(before, after, 1), caught)
        if not caught:
            fails.append(f"self-test: '{after}' in docs/results/{name} passes the results check")
    for page in sorted(results.glob("*.md")):
        lines = page.read_text().splitlines()
        for prose, header, rows in table_blocks(page.read_text()):
            seeds = [label for label, _ in rows if re.fullmatch(r"\d+", label)]
            if len(seeds) < 2:
                continue
            a, b = seeds[0], seeds[1]
            swapped = [re.sub(rf"^\|\s*{a}\s*\|", f"| {b} |", l) if l.startswith(f"| {a} |") else
                       re.sub(rf"^\|\s*{b}\s*\|", f"| {a} |", l) if l.startswith(f"| {b} |") else l
                       for l in lines]
            caught = []
            check_results_page(src, page, "\n".join(swapped), caught)
            if not caught:
                fails.append(f"self-test: {page.name}: seeds {a} and {b} swapped in the table of "
                             f"'{rows[0][0]}' pass the results check")
            break


def main():
    src = Path(sys.argv[1]).resolve()
    fails = []
    check_links(src, fails)
    check_user_pages(src, fails)
    check_results(src, fails)
    check_readme_figures(src, fails)
    if not fails:
        self_test(src, fails)
    for f in fails:
        print("FAIL: " + f)
    if not fails:
        print(f"PASS: {len(pages(src))} pages, {len(user_pages(src))} for users")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())

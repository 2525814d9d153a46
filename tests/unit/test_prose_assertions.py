#!/usr/bin/env python3
"""Tests read what the programs write for programs (RUN/events.jsonl, learner.csv), not what they
write for people: counts the assertion lines under tests/ that read prose out of a log or a summary,
and fails when there are more than LIMIT.

What counts, command by command in shell (lines joined while a single-quoted program is open or a
line ends in a backslash), line by line in Python and statement by statement in C++ (lines joined up
to a `;`, `{` or `}`), counted at the first line, in the files under tests/ (tests/bench/ included):
  - A prose source is a log or a summary: a file named *.log, *.out or summary.txt (a path that ends
    so on the line; C++'s ProcessSet::log(name) reads NAME.log), and a variable assigned on a line
    that names one (shell `name=`, Python `name =`, C++ `TYPE name =`). In shell and Python a
    variable assigned from such a variable is one too (a line grepped out of the summary); in C++
    a TEST starts afresh.
  - What a line says to people is taken off first: comments; a log a command writes to (after `>`
    or `>>`); in shell, everything from `fail` on (a failure's message), lines that only print
    (echo, printf, cat, head, tail) and commands whose status is thrown away (`|| true`); in C++,
    everything from the first `<<` on (a failed expectation's message).
  - What is left counts when it names a prose source and matches text in it: shell grep, egrep,
    sed, awk, wait_text or `=~`; Python re., ` in `, .find(, .startswith(, .count(; C++ find(,
    regex_search, regex_match, sregex_iterator, wait_for_text, wait_for_match, poll_log, any
    EXPECT_/ASSERT_, or an assignment from a call other than slurp that is given the text (a helper
    that parses it reads it too).
A helper's definition that reads a file it is given (lib.sh's wait_text, process_util.h's
poll_log) names no log and does not count; its callers do. Waiting on or reading
RUN/events.jsonl, learner.csv or a program's exit status does not count.

  tests/unit/test_prose_assertions.py SOURCE_DIR [LIMIT] [--list]
"""
import re
import sys
from pathlib import Path

SELF = "tests/unit/test_prose_assertions.py"
SUFFIXES = {".sh": "sh", ".py": "py", ".cpp": "cpp", ".h": "cpp"}
PROSE_FILE = re.compile(r"\.log\b|\.out\b|summary\.txt")
MATCH = {
    "sh": re.compile(r"\b(grep|egrep|sed|awk|wait_text)\b|=~"),
    "py": re.compile(r"\bre\.|\sin\s|\.find\(|\.startswith\(|\.count\("),
    "cpp": re.compile(
        r"\bfind\(|regex_search|regex_match|sregex_iterator|wait_for_text|wait_for_match|poll_log|\b(EXPECT|ASSERT)_"
    ),
}
ASSIGN = {
    "sh": re.compile(r"^\s*(?:local\s+)?([A-Za-z_]\w*)="),
    "py": re.compile(r"^\s*([A-Za-z_]\w*)\s*=[^=]"),
    "cpp": re.compile(r"^\s*(?:const\s+)?(?:[\w:]+(?:<[^=]*>)?)\s*&?\s+([A-Za-z_]\w*)\s*=[^=]"),
}
PRINTS = re.compile(r"^\s*(echo|printf|cat|head|tail)\b")


REDIRECT = {
    "sh": re.compile(r">>?\s*\S*\.log\b\S*"),
    "cpp": re.compile(r'>>?\s*"\s*\+\s*\w+\s*\+\s*"[^"]*\.log'),
}
TEST_START = re.compile(r"^\s*TEST(_F|_P)?\(")
CPP_CALL_ASSIGN = re.compile(r"=\s*(?!slurp\()[\w:]+\(")


def said_to_machines(kind, line):
    """The line without what it says to people (see the module's text)."""
    if kind in REDIRECT:
        line = REDIRECT[kind].sub(">", line)
    if kind == "sh":
        line = "\n".join(re.sub(r"(^|\s)#.*$", "", part) for part in line.split("\n"))
        if PRINTS.match(line) or re.search(r"\|\|\s*true\s*$", line):
            return ""
        m = re.search(r"(^|[\s|&;{(])fail\b", line)
        return line[: m.start()] if m else line
    if kind == "py":
        return re.sub(r"#.*$", "", line)
    line = re.sub(r"//.*$", "", line)
    i = line.find("<<")
    return line[:i] if i >= 0 else line


def names_prose(kind, text, tainted):
    if PROSE_FILE.search(text):
        return True
    if kind == "cpp":
        text = re.sub(r'"(\\.|[^"\\])*"', '""', text)  # a variable's name inside a literal is not the variable
    for v in tainted:
        pattern = r"\$\{?%s\b" % v if kind == "sh" else r"\b%s\b" % v
        if re.search(pattern, text):
            return True
    return False


def in_single_quotes(text):
    """Whether a shell text ends inside a single-quoted string (quotes inside double quotes, and
    escaped ones, do not count)."""
    state, i = None, 0
    while i < len(text):
        c = text[i]
        if state is None:
            if c == "\\":
                i += 1
            elif c == "#" and (i == 0 or text[i - 1] in " \t\n"):
                j = text.find("\n", i)
                i = len(text) if j < 0 else j
                continue
            elif c in "'\"":
                state = c
        elif state == '"':
            if c == "\\":
                i += 1
            elif c == '"':
                state = None
        elif c == "'":
            state = None
        i += 1
    return state == "'"


def units(path, kind):
    """(line number, text) of each line, or in C++ of each statement, comments taken off."""
    lines = path.read_text(encoding="utf-8", errors="replace").splitlines()
    if kind == "py":
        yield from enumerate(lines, 1)
        return
    if kind == "sh":
        # A command goes on while a single-quoted text (an awk or Python program) is open, or after
        # a line that ends in a backslash.
        start, parts = 0, []
        for n, raw in enumerate(lines, 1):
            if not parts:
                start = n
                if raw.lstrip().startswith("#"):
                    continue
            parts.append(raw)
            text = "\n".join(parts)
            if not in_single_quotes(text) and not raw.endswith("\\"):
                yield start, text
                parts = []
        if parts:
            yield start, "\n".join(parts)
        return
    in_block_comment, start, parts = False, 0, []
    for n, raw in enumerate(lines, 1):
        if in_block_comment:
            if "*/" not in raw:
                continue
            raw, in_block_comment = raw.split("*/", 1)[1], False
        if "/*" in raw and "*/" not in raw:
            raw, in_block_comment = raw.split("/*", 1)[0], True
        raw = re.sub(r"//.*$", "", raw)
        if not raw.strip():
            continue
        if not parts:
            start = n
        parts.append(raw.strip())
        if raw.rstrip().endswith((";", "{", "}")) or raw.lstrip().startswith("#"):
            yield start, " ".join(parts)
            parts = []
    if parts:
        yield start, " ".join(parts)


def count_file(path, kind):
    """The lines of one file that read prose: [(line number, text)]."""
    found, tainted = [], set()
    for n, raw in units(path, kind):
        if kind == "cpp" and TEST_START.match(raw):
            tainted = set()
        text = said_to_machines(kind, raw)
        if not text.strip():
            continue
        prose = names_prose(kind, text, tainted)
        a = ASSIGN[kind].match(text)
        direct = PROSE_FILE.search(text) or (kind == "cpp" and ".log(" in text)
        if a and (direct or (prose and kind != "cpp")):
            tainted.add(a.group(1))
        elif a:
            tainted.discard(a.group(1))
        reads = MATCH[kind].search(text) or (kind == "cpp" and a and CPP_CALL_ASSIGN.search(text))
        if prose and reads:
            found.append((n, " ".join(raw.split())[:160]))
    return found


# The rule on examples: (kind, text, lines that count). Checked before every count.
EXAMPLES = [
    ("sh", 'grep -q "lost 0" "$run/summary.txt" || fail "summary: $(cat "$run/summary.txt")"', [1]),
    ("sh", "r=$(awk '\n  $2 == \"x\" { n++ }\n  END { print n }' \"$dir/worker.log\")", [1]),
    ("sh", 'wait_text "$dir/worker.log" "joined experiment" 30 || fail "no join: $(tail -3 "$dir/worker.log")"', [1]),
    ("sh", '[ $rc = 0 ] || fail "learner exited $rc: $(tail -5 "$dir/learner.log")"', []),
    ("sh", 'grep -m1 -A30 "ERROR" "$B/fuzz.log" || true', []),
    ("sh", '"$learner" --config c >"$dir/learner.log" 2>&1 & pids+=($!)', []),
    ("sh", 's=$(cat "$run/summary.txt")\nline=$(grep "^worker" <<<"$s")\n[[ $line =~ lost\\ 0 ]] || fail x', [2, 3]),
    ("sh", 'events "$run" summary | grep -q \'"batches_lost":0\' || fail "lost: $(grep ok "$run/summary.txt")"', []),
    ("cpp", 'const std::string summary = slurp(run + "/summary.txt");\nEXPECT_NE(summary.find("x"), npos) << summary;', [2]),
    ("cpp", 'ASSERT_EQ(wait_for(p, 60), 0) << set.log("learner");', []),
    ("cpp", 'EXPECT_NE(set.log("worker").find("started"), std::string::npos);', [1]),
    ("cpp", 'const std::string summary = slurp(run + "/summary.txt");\nauto m = batches_line(summary);', [2]),
    ("cpp", 'ASSERT_EQ(std::system(("bash " + pki + " > " + d + "/pki.log 2>&1").c_str()), 0);', []),
    ("cpp", 'const std::string summary = slurp(d + "/summary.txt");\nTEST(A, B) {\nEXPECT_TRUE(summary.empty());', []),
    ("cpp", 'const double u = number_after(slurp(run + "/summary.txt"), "updates");', [1]),
    ("cpp", 'std::string w = set.log("w");\nASSERT_TRUE(std::regex_search(\n    w, m, re))\n    << w;', [2]),
    ("cpp", 'const std::string w3 = set.log("w3");\nEXPECT_TRUE(streams_of(s, "w3").empty());', []),
    ("cpp", 'const nlohmann::json s = summary_event(run);\nEXPECT_EQ(s.value("batches_lost", -1), 0) << s;', []),
]


def check_rule():
    import tempfile

    for kind, text, want in EXAMPLES:
        ext = {"sh": ".sh", "cpp": ".cpp", "py": ".py"}[kind]
        with tempfile.NamedTemporaryFile("w", suffix=ext, delete=False) as f:
            f.write(text + "\n")
        got = [n for n, _ in count_file(Path(f.name), kind)]
        Path(f.name).unlink()
        if got != want:
            print(f"the rule counts lines {got} of this {kind}, not {want}:\n{text}")
            return False
    return True


def main():
    if not check_rule():
        return 2
    args = [a for a in sys.argv[1:] if a != "--list"]
    root = Path(args[0] if args else ".")
    limit = int(args[1]) if len(args) > 1 else 10
    total, per_file = 0, []
    for p in sorted((root / "tests").rglob("*")):
        rel = p.relative_to(root).as_posix()
        if not p.is_file() or p.suffix not in SUFFIXES or rel == SELF:
            continue
        found = count_file(p, SUFFIXES[p.suffix])
        if found:
            per_file.append((rel, found))
            total += len(found)
    for rel, found in per_file:
        print(f"{rel}: {len(found)}")
        if "--list" in sys.argv:
            for n, line in found:
                print(f"  {n}: {line}")
    print(f"{total} assertion lines read prose from logs or summaries; at most {limit} may")
    return 0 if total <= limit else 1


if __name__ == "__main__":
    sys.exit(main())

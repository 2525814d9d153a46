#!/usr/bin/env python3
"""No class or struct of the farm's C++ has more than LIMIT data members.

A class with more is doing several jobs (the learner's and the worker's services were such classes
before they became runners of parts). Counts the non-static data members declared in each class
body of the given folders, nested classes on their own; fails naming every class over the limit.

  tests/unit/test_class_sizes.py SOURCE_DIR [LIMIT]
"""
import re
import sys
from pathlib import Path

FOLDERS = ["common", "learner", "worker", "robots", "tools", "python"]


def strip(text):
    """The text without comments, string and character literals (same length, so braces stay put)."""
    out, i, n = [], 0, len(text)
    while i < n:
        c = text[i]
        if text.startswith("//", i):
            j = text.find("\n", i)
            j = n if j < 0 else j
            out.append(" " * (j - i))
            i = j
        elif text.startswith("/*", i):
            j = text.find("*/", i + 2)
            j = n if j < 0 else j + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c == '"' and text.startswith('R"', i - 1) and i > 0:
            m = re.match(r'"([^(]*)\(', text[i:])
            end = text.find(")" + (m.group(1) if m else "") + '"', i)
            j = n if end < 0 else end + len(m.group(1) if m else "") + 2
            out.append(re.sub(r"[^\n]", " ", text[i:j]))
            i = j
        elif c in "\"'":
            j = i + 1
            while j < n and text[j] != c:
                j += 2 if text[j] == "\\" else 1
            out.append(" " * (j + 1 - i))
            i = j + 1
        else:
            out.append(c)
            i += 1
    return "".join(out)


def matching(text, i):
    """Index of the brace closing the one at i."""
    depth = 0
    for j in range(i, len(text)):
        if text[j] == "{":
            depth += 1
        elif text[j] == "}":
            depth -= 1
            if depth == 0:
                return j
    return len(text) - 1


def drop_templates(s):
    prev = None
    while prev != s:
        prev = s
        s = re.sub(r"<[^<>]*>", "", s)
    return s


def members(body):
    """Names of the data members declared at the top level of a class body."""
    names, stmt, i = [], "", 0
    while i < len(body):
        c = body[i]
        if c == "{":
            j = matching(body, i)
            head = drop_templates(re.sub(r"\b(public|private|protected)\s*:", " ", stmt)).strip()
            if re.match(r"(class|struct|union|enum)\b", head) or "(" in head.split("=")[0]:
                # a nested type (its declarators, if any, follow the body) or a function body
                if "(" in head.split("=")[0] and not re.match(r"(class|struct|union|enum)\b", head):
                    stmt = ""
                    i = j + 1
                    continue
                stmt = "struct __nested__ "
            i = j + 1
            continue
        if c == ";":
            names += declared(stmt)
            stmt = ""
        else:
            stmt += c
        i += 1
    return names


def declared(stmt):
    s = re.sub(r"\b(public|private|protected)\s*:", " ", stmt).strip()
    if not s or re.match(r"(using|typedef|friend|static|template|enum|namespace)\b", s):
        return []
    if re.match(r"(class|struct|union)\s+\w+\s*$", s):  # a forward declaration
        return []
    s = s.replace("struct __nested__", "T")
    s = drop_templates(s)
    s = re.sub(r"=[^,]*", "", s)  # initializers
    if "(" in s or "operator" in s:
        return []  # a function or constructor
    out = []
    for part in s.split(","):
        m = re.search(r"(\w+)\s*(\[[^\]]*\])*\s*(:\s*\d+)?\s*$", part.strip())
        if m and not re.fullmatch(r"(const|volatile|mutable|unsigned|signed|int|long|short|char|bool|auto)", m.group(1)):
            out.append(m.group(1))
    return out


def classes(text):
    for m in re.finditer(r"\b(class|struct)\s+(?:alignas\s*\([^)]*\)\s*)?(\w+(?:::\w+)*)\s*(final\s*)?(:[^;{]*)?\{", text):
        start = m.end() - 1
        yield m.group(2), members(text[start + 1 : matching(text, start)])


def main():
    src = Path(sys.argv[1])
    limit = int(sys.argv[2]) if len(sys.argv) > 2 else 25
    over, seen = [], 0
    for folder in FOLDERS:
        for f in sorted((src / folder).rglob("*")):
            if f.suffix not in (".h", ".cpp") or "build" in f.parts:
                continue
            for name, m in classes(strip(f.read_text(errors="replace"))):
                seen += 1
                if len(m) > limit:
                    over.append(f"{f.relative_to(src)}: {name} has {len(m)} data members ({', '.join(m)})")
    if seen < 50:
        print(f"FAIL: only {seen} classes found under {', '.join(FOLDERS)}")
        return 1
    for line in over:
        print("FAIL: " + line)
    if not over:
        print(f"PASS: none of {seen} classes has more than {limit} data members")
    return 1 if over else 0


if __name__ == "__main__":
    sys.exit(main())

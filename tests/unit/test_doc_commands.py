#!/usr/bin/env python3
"""The commands of the guides name options their programs have. Every line of a code block in
README.md and docs/guides/ that runs a farm program (farm-*, a benchmark, tools/*.py, a deploy/ or
tests/ script) is read, continuation lines joined; each --option it gives must be in that program's
--help (for a shell script, in its text). Fails naming the page, the program and the option.

  tests/unit/test_doc_commands.py SOURCE_DIR BUILD_DIR
"""
import re
import shlex
import subprocess
import sys
from pathlib import Path

PROGRAM = re.compile(r"(?:^|/)((?:farm-[a-z-]+)|(?:bench_[a-z0-9_]+)|(?:[a-z0-9_-]+\.(?:py|sh)))$")


def blocks(text):
    for m in re.finditer(r"```[^\n]*\n(.*?)```", text, flags=re.S):
        yield m.group(1)


def commands(block):
    joined = re.sub(r"\\\n\s*", " ", block)
    for line in joined.splitlines():
        line = line.split(" #")[0].strip()
        if line.startswith("#") or line.startswith("$ "):
            line = line[2:] if line.startswith("$ ") else ""
        if not line:
            continue
        for part in re.split(r"\s*(?:&&|\|\||;|\||&)\s*", line):
            try:
                words = shlex.split(part.replace("[", " ").replace("]", " "))
            except ValueError:
                continue
            while words and ("=" in words[0] and not words[0].startswith("-")):
                words.pop(0)  # VAR=value before the program
            if words and words[0] in ("env", "timeout", "sudo", "python3", "/usr/bin/python3", "bash", "nohup"):
                words = [w for w in words[1:] if not w.startswith("-u")]
                while words and re.fullmatch(r"\d+|[A-Z_]+|-[a-z]", words[0]):
                    words.pop(0)
            if words and PROGRAM.search(words[0]):
                yield words[0], [w.split("=")[0] for w in words[1:] if w.startswith("--")]


def help_text(name, src, build, cache):
    if name in cache:
        return cache[name]
    text = None
    if name.endswith(".sh") or name.endswith(".py"):
        found = list(src.glob("deploy/" + name)) + list(src.glob("tests/**/" + name)) + list(src.glob("tools/" + name)) + list(src.glob("python/**/" + name))
        if found:
            text = found[0].read_text(errors="replace")
            if name.endswith(".py"):
                run = subprocess.run([sys.executable, str(found[0]), "--help"], capture_output=True, text=True, timeout=60)
                text += run.stdout + run.stderr
    else:
        exe = [p for p in build.rglob(name) if p.is_file() and p.stat().st_mode & 0o111]
        if exe:
            run = subprocess.run([str(exe[0]), "--help"], capture_output=True, text=True, timeout=60)
            text = run.stdout + run.stderr
    cache[name] = text
    return text


def main():
    src, build = Path(sys.argv[1]).resolve(), Path(sys.argv[2]).resolve()
    pages = [src / "README.md"] + sorted((src / "docs" / "guides").glob("*.md"))
    fails, checked, cache = [], 0, {}
    for page in pages:
        for block in blocks(page.read_text()):
            for prog, options in commands(block):
                name = PROGRAM.search(prog).group(1)
                text = help_text(name, src, build, cache)
                if text is None:
                    fails.append(f"{page.relative_to(src)}: {prog}: no such program in the build or the source")
                    continue
                for opt in options:
                    checked += 1
                    if not re.search(re.escape(opt) + r"(?![\w-])", text):
                        fails.append(f"{page.relative_to(src)}: {name} has no option {opt} (not in its --help)")
    for f in fails:
        print("FAIL: " + f)
    if checked < 20:
        print(f"FAIL: only {checked} options found in the guides' commands")
        return 1
    if not fails:
        print(f"PASS: {checked} options of the guides' commands are in their programs' --help")
    return 1 if fails else 0


if __name__ == "__main__":
    sys.exit(main())

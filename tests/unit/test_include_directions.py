#!/usr/bin/env python3
"""The layers include downwards only. Each #include of a C++ source is resolved to the folder that
holds it, the way the build's include paths find it (the includer's own folder first, then the
folders its layer may include), and these must hold:
  - common/ includes nothing from robots/, learner/, worker/ or tools/;
  - robots/ includes nothing from learner/, worker/ or tools/;
  - learner/algorithms/ (its sub-folders too) includes nothing of the farm around it: no header of
    learner/ outside it, of robots/, worker/ or tools/, no DDS header of common/ (the bus, trust,
    shared-memory leftovers), no generated wire type and no Fast DDS; and its interface,
    algorithm.h, stays at most 80 lines.
A name generated at build time (farm_config.pb.h) is found in no folder and is not a violation.
Fails naming the file, the header and the folder it comes from.
    tests/unit/test_include_directions.py SOURCE_DIR
"""
import os
import re
import sys

SOURCES = (".h", ".hpp", ".cpp", ".cc", ".cu", ".def")
INCLUDE = re.compile(r'^\s*#\s*include\s*[<"]([^>"]+)[>"]', re.M)
LAYERS = ("common", "robots", "learner", "worker", "tools")
# Headers of common/ that are the bus (compiled into farm_dds), and the generated wire types.
DDS_HEADERS = {"common/dds.h", "common/trust.h", "common/shm_leftovers.h"}
WIRE_NAMES = re.compile(r"^(farm|farmPubSubTypes|farmCdrAux|farm_idl)\.h(pp)?$|^(fastdds|fastrtps|fastcdr)/")


def files_under(root, folder):
    out = []
    for d, _, names in os.walk(os.path.join(root, folder)):
        out += [os.path.join(d, n) for n in names if n.endswith(SOURCES)]
    return sorted(out)


class Tree:
    def __init__(self, root):
        self.root = root
        # Every source of the layers by its path relative to the root.
        self.all = {os.path.relpath(f, root) for layer in LAYERS for f in files_under(root, layer)}

    def resolve(self, includer, name, search):
        """The repository path `name` means in `includer`: its own folder, then each folder of `search`
        (the include paths of its layer, in order); else any layer's file whose path ends in /name
        (a header of another layer reached through that layer's include path); None: generated or
        a system header."""
        for d in [os.path.dirname(includer)] + list(search):
            p = os.path.normpath(os.path.join(d, name))
            if p in self.all:
                return p
        found = sorted(p for p in self.all if p.endswith("/" + name))
        return found[0] if found else None


def includes(root, rel):
    with open(os.path.join(root, rel), encoding="utf-8", errors="replace") as f:
        return INCLUDE.findall(f.read())


def layer_of(path):
    return path.split("/", 1)[0]


def main():
    root = os.path.abspath(sys.argv[1] if len(sys.argv) > 1 else ".")
    tree = Tree(root)
    failures, checked = [], {}

    def check(folder, search, forbidden, label):
        n = 0
        for f in files_under(root, folder):
            rel = os.path.relpath(f, root)
            n += 1
            for name in includes(root, rel):
                if label == "algorithms" and WIRE_NAMES.search(name):
                    failures.append(f"{rel} includes {name} (the wire types or Fast DDS)")
                    continue
                p = tree.resolve(rel, name, search)
                if p is None:
                    continue
                why = forbidden(p)
                if why:
                    failures.append(f"{rel} includes {name}: {p} is {why}")
        checked[folder] = n

    check("common", ["common"], lambda p: None if layer_of(p) == "common" else f"in {layer_of(p)}/", "common")
    check("robots", ["robots", "common"],
          lambda p: f"in {layer_of(p)}/" if layer_of(p) in ("learner", "worker", "tools") else None, "robots")

    def algorithms_forbid(p):
        if p.startswith("learner/algorithms/"):
            return None
        if p in DDS_HEADERS:
            return "the bus (common/'s DDS part)"
        if layer_of(p) == "common":
            return None
        return f"in {os.path.dirname(p)}/, outside learner/algorithms/"

    alg = "learner/algorithms"
    alg_dirs = [alg] + sorted(os.path.join(alg, d) for d in os.listdir(os.path.join(root, alg))
                              if os.path.isdir(os.path.join(root, alg, d)))
    check(alg, alg_dirs + ["common"], algorithms_forbid, "algorithms")

    for folder, minimum in (("common", 10), ("robots", 20), (alg, 10)):
        if checked.get(folder, 0) < minimum:
            failures.append(f"only {checked.get(folder, 0)} sources found in {folder}/ (the check reads none?)")
    with open(os.path.join(root, alg, "algorithm.h"), encoding="utf-8") as f:
        lines = sum(1 for _ in f)
    if lines > 80:
        failures.append(f"{alg}/algorithm.h has {lines} lines, more than 80")

    for m in failures:
        print("FAIL:", m)
    if failures:
        return 1
    print("PASS: " + ", ".join(f"{n} sources of {d}/" for d, n in checked.items()) + " include downwards only")
    return 0


if __name__ == "__main__":
    sys.exit(main())

#!/usr/bin/env python3
"""The import graph between the files of each crate of this workspace, and
the two rules CI holds it to (issue 29):

1. no circle between files: file A imports file B when A names an item that
   B defines, through a `use` or an inline `crate::`/`super::`/`self::`
   path (or a path that starts with a name a `use` bound, or with a child
   module), with `pub use` re-exports followed to the file that defines the
   item;
2. the science core of `shared` (sim, env, ppo, analysis, sample.rs,
   optimize) imports nothing from the wire module (`shared/src/api.rs` or
   `api/`): neither an item the wire module defines nor any path through it.

Only what the library or binary is built from counts: the module tree is
read from each crate's `src/lib.rs`, `src/main.rs` and `src/bin/*.rs` by its
`mod` declarations; items and `mod` declarations under `#[cfg(test)]` are
left out, and so are tests/, benches/ and examples/ (other targets).

Two things are not imports: a `pub use` (it hands a name on; the file that
names the item through it imports the defining file), and a module naming
an item its own ancestor module defines (the parent is the module's
namespace: `super::Error` in a child of the module that defines `Error`).

Usage: import_graph.py [ROOT] [--edges]. Prints each circle and each layer
breach, then a count line; exits 1 when there is either, 0 when there is
none, 2 on a usage error.
"""
import pathlib
import re
import sys

# Layer rules, per crate directory (relative to the root): file prefixes of
# the lower layer, and of the module it must not import from.
LAYERS = {
    "shared": {
        "lower": ("src/sim/", "src/sim.rs", "src/env/", "src/env.rs",
                  "src/ppo/", "src/ppo.rs", "src/analysis/", "src/analysis.rs",
                  "src/sample.rs", "src/optimize/", "src/optimize.rs"),
        "upper": ("src/api.rs", "src/api/"),
        "what": "science core imports the wire module",
    },
}

IDENT = r"[A-Za-z_][A-Za-z0-9_]*"
KEYWORD_PATHS = {"crate", "super", "self"}


# ---------------------------------------------------------------- lexing

def strip_code(src):
    """The source with comments removed and string and char literals
    emptied, lifetimes kept; line breaks are kept so offsets stay
    meaningful."""
    out = []
    i, n = 0, len(src)
    while i < n:
        c = src[i]
        nxt = src[i + 1] if i + 1 < n else ""
        if c == "/" and nxt == "/":
            j = src.find("\n", i)
            i = n if j < 0 else j
            continue
        if c == "/" and nxt == "*":
            depth, i = 1, i + 2
            while i < n and depth:
                if src.startswith("/*", i):
                    depth, i = depth + 1, i + 2
                elif src.startswith("*/", i):
                    depth, i = depth - 1, i + 2
                else:
                    if src[i] == "\n":
                        out.append("\n")
                    i += 1
            out.append(" ")
            continue
        raw = re.match(r'b?r(#*)"', src[i:i + 260]) if c in "br" else None
        if raw and (i == 0 or not (src[i - 1].isalnum() or src[i - 1] == "_")):
            end = '"' + raw.group(1)
            j = src.find(end, i + raw.end())
            j = n if j < 0 else j + len(end)
            out.append('""' + "\n" * src.count("\n", i, j))
            i = j
            continue
        if c == '"' or (c == "b" and nxt == '"' and
                        (i == 0 or not (src[i - 1].isalnum() or src[i - 1] == "_"))):
            j = i + (2 if c == "b" else 1)
            while j < n and src[j] != '"':
                j += 2 if src[j] == "\\" else 1
            out.append('""' + "\n" * src.count("\n", i, j))
            i = j + 1
            continue
        if c == "'":
            # A char literal ('a', '\n', '\u{1F600}'), else a lifetime.
            m = re.match(r"'(?:\\(?:u\{[0-9a-fA-F]+\}|x[0-9a-fA-F]{2}|.)|[^\\'\n])'", src[i:i + 12])
            if m:
                out.append("' '")
                i += m.end()
                continue
        out.append(c)
        i += 1
    return "".join(out)


def matching_brace(text, open_at):
    """Index just past the `}` that closes the `{` at `open_at`."""
    depth = 0
    for j in range(open_at, len(text)):
        if text[j] == "{":
            depth += 1
        elif text[j] == "}":
            depth -= 1
            if depth == 0:
                return j + 1
    return len(text)


CFG_TEST = re.compile(r"#\[cfg\(\s*test\s*\)\]")


def drop_test_items(code):
    """`code` without the items under `#[cfg(test)]`, and the names of the
    `mod x;` declarations among them (files that are test-only)."""
    test_mods = set()
    while True:
        m = CFG_TEST.search(code)
        if not m:
            return code, test_mods
        j = m.end()
        # further attributes of the same item
        while True:
            a = re.match(r"\s*#\[", code[j:])
            if not a:
                break
            depth, k = 0, j + a.end() - 1
            while k < len(code):
                if code[k] == "[":
                    depth += 1
                elif code[k] == "]":
                    depth -= 1
                    if depth == 0:
                        break
                k += 1
            j = k + 1
        decl = re.match(r"\s*(?:pub(?:\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*;", code[j:])
        if decl:
            test_mods.add(decl.group(1))
            end = j + decl.end()
        else:
            semi, brace = code.find(";", j), code.find("{", j)
            if brace >= 0 and (semi < 0 or brace < semi):
                end = matching_brace(code, brace)
            else:
                end = (semi + 1) if semi >= 0 else len(code)
        code = code[:m.start()] + "\n" * code.count("\n", m.start(), end) + code[end:]


def split_top(body, sep=","):
    """Splits `body` at `sep` outside braces."""
    parts, depth, cur = [], 0, []
    for ch in body:
        if ch == "{":
            depth += 1
        elif ch == "}":
            depth -= 1
        if ch == sep and depth == 0:
            parts.append("".join(cur))
            cur = []
        else:
            cur.append(ch)
    parts.append("".join(cur))
    return [p.strip() for p in parts if p.strip()]


def use_leaves(tree, prefix=()):
    """Flattens a use tree into (path segments, bound name or None for a
    glob): `a::{b, c::{d as e, self}, f::*}` gives (a,b) b, (a,c,d) e,
    (a,c) c, (a,f,*) None."""
    tree = " ".join(tree.split())
    if tree.startswith("::"):
        tree = tree[2:]
    brace = tree.find("{")
    if brace >= 0:
        head = [s.strip() for s in tree[:brace].split("::") if s.strip()]
        inner = tree[brace + 1:tree.rfind("}")]
        out = []
        for part in split_top(inner):
            out += use_leaves(part, prefix + tuple(head))
        return out
    alias = None
    m = re.match(r"^(.*?)\s+as\s+(" + IDENT + r")$", tree)
    if m:
        tree, alias = m.group(1), m.group(2)
    segs = prefix + tuple(s.strip() for s in tree.split("::") if s.strip())
    if not segs:
        return []
    if segs[-1] == "self":
        segs = segs[:-1]
        if not segs:
            return []
    if segs[-1] == "*":
        return [(segs, None)]
    return [(segs, alias or segs[-1])]


USE = re.compile(r"(?P<vis>\bpub(?:\s*\([^)]*\))?\s+)?\buse\s+(?P<tree>[^;]+);")
ITEM = re.compile(r"\b(?:fn|struct|enum|union|trait|type|const|static|macro_rules!)\s+(" + IDENT + r")")
PATH = re.compile(r"(?<![\w:])(" + IDENT + r"(?:\s*::\s*" + IDENT + r")+)")
MOD_DECL = re.compile(r"(?:^|[;{}\s])(?:pub(?:\s*\([^)]*\))?\s+)?mod\s+(" + IDENT + r")\s*;")


# ---------------------------------------------------------------- one crate

class Module:
    def __init__(self, path, file, code):
        self.path = path          # tuple of module names from the crate root
        self.file = file          # pathlib.Path
        self.code = code          # stripped, without test items
        self.defines = set(ITEM.findall(code))
        self.uses = []            # (segments, bound name or None, is_pub)
        for m in USE.finditer(code):
            for segs, name in use_leaves(m.group("tree")):
                self.uses.append((segs, name, bool(m.group("vis"))))


def module_file(dir_, name):
    for cand in (dir_ / f"{name}.rs", dir_ / name / "mod.rs"):
        if cand.is_file():
            return cand
    return None


def load_tree(root_file):
    """Every module reachable from a crate root file by `mod x;`."""
    mods = {}

    def visit(path, file, child_dir):
        code, test_mods = drop_test_items(strip_code(file.read_text(errors="replace")))
        mods[path] = Module(path, file, code)
        for name in MOD_DECL.findall(code):
            if name in test_mods:
                continue
            f = module_file(child_dir, name)
            if f is not None:
                visit(path + (name,), f, f.parent if f.name == "mod.rs" else f.with_suffix(""))

    visit((), root_file, root_file.parent)
    return mods


class Crate:
    def __init__(self, root_file):
        self.mods = load_tree(root_file)

    def resolve_module_prefix(self, cur, segs):
        """(module, rest of the segments) for a path named in module `cur`,
        or None when it starts outside this crate."""
        if not segs:
            return None
        head = segs[0]
        if head == "crate":
            base, rest = (), list(segs[1:])
        elif head == "super":
            base, rest = cur, list(segs)
            while rest and rest[0] == "super":
                base, rest = base[:-1], rest[1:]
        elif head == "self":
            base, rest = cur, list(segs[1:])
        elif cur + (head,) in self.mods:
            base, rest = cur, list(segs)
        else:
            return None
        while rest and base + (rest[0],) in self.mods:
            base, rest = base + (rest[0],), rest[1:]
        return base, rest

    def bound_names(self, mod):
        """Names the `use`s of `mod` bind: name -> segments."""
        return {name: segs for segs, name, _ in self.mods[mod].uses if name}

    def defining(self, mod, item, seen=None):
        """The module that defines `item` as named in `mod`, following
        `pub use` re-exports (single and glob)."""
        seen = seen or set()
        if item is None or (mod, item) in seen:
            return mod
        seen.add((mod, item))
        m = self.mods[mod]
        if item in m.defines:
            return mod
        for segs, name, is_pub in m.uses:
            if not is_pub:
                continue
            if name == item:
                r = self.resolve_module_prefix(mod, segs[:-1] + (segs[-1],))
                if r is None:
                    return mod
                tmod, rest = r
                return self.defining(tmod, rest[0] if rest else None, seen)
            if name is None:  # glob re-export
                r = self.resolve_module_prefix(mod, segs[:-1])
                if r and not r[1]:
                    found = self.defining(r[0], item, seen)
                    if found != r[0] or item in self.mods[r[0]].defines:
                        return found
        return mod

    def target(self, cur, segs):
        """The module whose file defines what `segs` names in `cur`, and
        the modules the path passes through; None outside the crate."""
        segs = tuple(segs)
        if segs and segs[0] not in KEYWORD_PATHS and cur + (segs[0],) not in self.mods:
            bound = self.bound_names(cur).get(segs[0])
            if bound is None:
                return None
            segs = bound + segs[1:]
        r = self.resolve_module_prefix(cur, segs)
        if r is None:
            return None
        mod, rest = r
        passed = [mod[:k] for k in range(1, len(mod) + 1)]
        if not rest:
            return mod, passed
        tgt = self.defining(mod, rest[0])
        return tgt, passed

    def edges(self):
        """{module: {module it imports: [what it named]}} and every module
        path each module's paths pass through."""
        out, through = {}, {}
        for cur, m in self.mods.items():
            named = out.setdefault(cur, {})
            passes = through.setdefault(cur, set())
            paths = [segs for segs, _, is_pub in m.uses if not is_pub]
            # globs: the module itself is what is named
            paths = [s[:-1] if s[-1] == "*" else s for s in paths]
            text = USE.sub(" ", m.code)
            for p in PATH.findall(text):
                paths.append(tuple(s.strip() for s in p.split("::")))
            for segs in paths:
                if not segs:
                    continue
                t = self.target(cur, segs)
                if t is None:
                    continue
                tgt, passed = t
                passes.update(passed)
                if tgt == cur or cur[:len(tgt)] == tgt:
                    continue  # itself, or an ancestor's item: its namespace
                named.setdefault(tgt, []).append("::".join(segs))
        return out, through


def circles(graph):
    """Strongly connected components with more than one node (Tarjan,
    iterative)."""
    index, low, stack, on, found = {}, {}, [], set(), []
    counter = 0
    for start in graph:
        if start in index:
            continue
        work = [(start, iter(graph[start]))]
        index[start] = low[start] = counter
        counter += 1
        stack.append(start)
        on.add(start)
        while work:
            v, it = work[-1]
            advanced = False
            for w in it:
                if w not in index:
                    index[w] = low[w] = counter
                    counter += 1
                    stack.append(w)
                    on.add(w)
                    work.append((w, iter(graph.get(w, ()))))
                    advanced = True
                    break
                if w in on:
                    low[v] = min(low[v], index[w])
            if advanced:
                continue
            work.pop()
            if work:
                low[work[-1][0]] = min(low[work[-1][0]], low[v])
            if low[v] == index[v]:
                comp = []
                while True:
                    w = stack.pop()
                    on.discard(w)
                    comp.append(w)
                    if w == v:
                        break
                if len(comp) > 1:
                    found.append(comp)
    return found


# ---------------------------------------------------------------- workspace

def crate_roots(root):
    for toml in sorted(root.rglob("Cargo.toml")):
        rel = toml.relative_to(root)
        if any(p in ("target", ".git") or p.startswith("target") for p in rel.parts[:-1]):
            continue
        src = toml.parent / "src"
        if not src.is_dir():
            continue
        files = [f for f in (src / "lib.rs", src / "main.rs") if f.is_file()]
        files += sorted((src / "bin").glob("*.rs")) if (src / "bin").is_dir() else []
        yield toml.parent, files


def check(root, show_edges=False):
    """Prints the circles and layer breaches below `root`; their count."""
    problems = 0
    for crate_dir, root_files in crate_roots(root):
        crate_rel = crate_dir.relative_to(root).as_posix()
        crate_rel = "" if crate_rel == "." else crate_rel
        rules = LAYERS.get(crate_rel)
        graph, labels = {}, {}
        for rf in root_files:
            crate = Crate(rf)
            edges, through = crate.edges()

            def fname(mod):
                return crate.mods[mod].file.relative_to(crate_dir).as_posix()

            for mod, named in edges.items():
                a = fname(mod)
                graph.setdefault(a, set())
                for tgt, what in named.items():
                    b = fname(tgt)
                    graph[a].add(b)
                    labels.setdefault((a, b), what[0])
                    if show_edges:
                        print(f"edge: {crate_dir.relative_to(root) / a} -> {b} ({what[0]})")
            if rules:
                for mod, named in edges.items():
                    a = fname(mod)
                    if not a.startswith(rules["lower"]):
                        continue
                    hits = {fname(t): "a path through " + "::".join(t)
                            for t in through[mod]
                            if fname(t).startswith(rules["upper"])}
                    hits.update({fname(t): w[0] for t, w in named.items()
                                 if fname(t).startswith(rules["upper"])})
                    for b, what in sorted(hits.items()):
                        problems += 1
                        print(f"layer: {crate_dir.relative_to(root) / a} -> "
                              f"{crate_dir.relative_to(root) / b} ({rules['what']}: {what})")
        for comp in circles(graph):
            problems += 1
            ring = sorted(comp)
            pairs = ", ".join(f"{a} -> {b} ({labels[(a, b)]})"
                              for a in ring for b in ring if (a, b) in labels)
            names = " <-> ".join((crate_dir.relative_to(root) / f).as_posix() for f in ring)
            print(f"circle: {names}\n  because: {pairs}")
    return problems


def main(argv):
    args = [a for a in argv if not a.startswith("--")]
    flags = [a for a in argv if a.startswith("--")]
    if len(args) > 1 or any(f != "--edges" for f in flags):
        print("usage: import_graph.py [ROOT] [--edges]", file=sys.stderr)
        return 2
    root = pathlib.Path(args[0] if args else ".").resolve()
    problems = check(root, show_edges="--edges" in flags)
    print(f"{problems} import problem(s): circles between files or science -> wire imports"
          if problems else "import graph: no circle between files, no science -> wire import")
    return 1 if problems else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))

#!/usr/bin/env python3
"""Handlers stay thin: no `pub async fn` in the coordinator's HTTP layer
(`coordinator/src/routes/`) is longer than 40 lines, counted from the line
of its `fn` to the line of its closing brace. A handler parses the
request, calls the domain layer and maps the answer; rules that make one
longer belong in `coordinator/src/domain/`.

Usage: handler_length.py [ROOT]. Prints each handler over the limit, then
a count line; exits 1 when there is one, 0 when there is none, 2 on a
usage error.
"""
import pathlib
import re
import sys

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent))
from import_graph import strip_code  # noqa: E402

ROUTES = "coordinator/src/routes"
MAX_LINES = 40
FN = re.compile(r"\bpub\s+async\s+fn\s+([A-Za-z_][A-Za-z0-9_]*)")


def handlers(src):
    """(name, first line, last line) of each `pub async fn` with a body."""
    code = strip_code(src)
    out = []
    for m in FN.finditer(code):
        i = m.end()
        # The body's opening brace: the first `{` outside the signature's
        # parentheses and angle brackets; a `;` first means no body.
        depth = 0
        while i < len(code):
            c = code[i]
            if c in "(<[":
                depth += 1
            elif c in ")>]" and not (c == ">" and code[i - 1] == "-"):
                depth -= 1
            elif c == ";" and depth <= 0:
                i = -1
                break
            elif c == "{" and depth <= 0:
                break
            i += 1
        if i < 0 or i >= len(code):
            continue
        depth, j = 0, i
        while j < len(code):
            if code[j] == "{":
                depth += 1
            elif code[j] == "}":
                depth -= 1
                if depth == 0:
                    break
            j += 1
        first = code.count("\n", 0, m.start()) + 1
        last = code.count("\n", 0, j) + 1
        out.append((m.group(1), first, last))
    return out


def main(argv):
    if len(argv) > 2:
        print(__doc__, file=sys.stderr)
        return 2
    root = pathlib.Path(argv[1] if len(argv) > 1 else ".")
    routes = root / ROUTES
    if not routes.is_dir():
        print(f"handler_length: no {ROUTES} under {root}", file=sys.stderr)
        return 2
    long, total, longest = [], 0, ("", 0)
    for path in sorted(routes.rglob("*.rs")):
        rel = path.relative_to(root)
        for name, first, last in handlers(path.read_text()):
            n = last - first + 1
            total += 1
            if n > longest[1]:
                longest = (f"{rel}::{name}", n)
            if n > MAX_LINES:
                long.append(f"{rel}:{first}: handler {name} is {n} lines (limit {MAX_LINES})")
    for line in long:
        print(line)
    print(f"{len(long)} handlers over {MAX_LINES} lines of {total} "
          f"(longest: {longest[0]}, {longest[1]} lines)")
    return 1 if long else 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))

#!/usr/bin/env bash
# CI step: the documentation as an mdBook (docs/book.toml, docs/SUMMARY.md).
# Installs the pinned mdbook with `cargo install` unless that version is
# already on PATH, builds the book into target/book, and fails on a broken
# link: the link check is `cargo test -p irlgrid --test doc_anchors` (every
# relative link and cited anchor of the README and the book resolves, every
# page is a chapter, no issue numbers), run here again so that this step
# alone proves the book, and a build whose output misses a chapter fails.
set -euo pipefail
cd "$(dirname "$0")/../.."

MDBOOK_VERSION=0.4.52
have=$(mdbook --version 2>/dev/null || true)
if [ "$have" != "mdbook v$MDBOOK_VERSION" ]; then
  echo "installing mdbook $MDBOOK_VERSION (found: ${have:-none})"
  cargo install mdbook --locked --version "$MDBOOK_VERSION" --quiet
fi
export PATH="${CARGO_HOME:-$HOME/.cargo}/bin:$PATH"

out=${CARGO_TARGET_DIR:-target}/book
case $out in /*) ;; *) out=$(pwd)/$out ;; esac
# mdbook prints broken SUMMARY entries and missing files as errors and
# exits non-zero; warnings about anything else fail the step too.
log=$(mktemp)
trap 'rm -f "$log"' EXIT
mdbook build docs --dest-dir "$out" 2>&1 | tee "$log"
[ "${PIPESTATUS[0]}" = 0 ] || { echo "FAIL: mdbook build docs" >&2; exit 1; }
if grep -E '\b(WARN|ERROR)\b' "$log"; then
  echo "FAIL: mdbook reported problems (above)" >&2
  exit 1
fi

# Every chapter of SUMMARY.md became a page.
missing=0
while read -r page; do
  html="$out/${page%.md}.html"
  [ -s "$html" ] || { echo "FAIL: no $html for the chapter $page" >&2; missing=1; }
done < <(grep -oE '\]\([^)#]+\.md\)' docs/SUMMARY.md | sed -E 's/^\]\((.*)\)$/\1/')
[ "$missing" = 0 ] || exit 1

# The built pages themselves: every relative href of a chapter's text names
# a file of the book and, with #anchor, an id of that page.
if command -v python3 >/dev/null 2>&1; then
  python3 - "$out" <<'PY'
import glob, html, os, re, sys
os.chdir(sys.argv[1])
pages = [p for p in glob.glob("**/*.html", recursive=True) if p not in ("print.html", "404.html")]
ids = {p: set(re.findall(r'\bid="([^"]+)"', open(p, errors="replace").read())) for p in pages}
bad = []
for p in pages:
    text = open(p, errors="replace").read()
    main = text[text.find("<main>"):text.find("</main>")]
    for href in map(html.unescape, re.findall(r'href="([^"]+)"', main)):
        if re.match(r"^[a-z]+:", href) or href.startswith("/"):
            continue
        path, _, anchor = href.partition("#")
        target = os.path.normpath(os.path.join(os.path.dirname(p), path)) if path else p
        if not os.path.exists(target):
            bad.append(f"{p}: {href}: no such file in the book")
        elif anchor and target.endswith(".html") and anchor not in ids.get(target, set()):
            bad.append(f"{p}: {href}: no id {anchor!r} on {target}")
print("\n".join(bad) or f"built pages: every relative link of {len(pages)} pages resolves")
sys.exit(1 if bad else 0)
PY
else
  echo "note: no python3; the built pages' links are not re-checked (doc_anchors below checks the sources)"
fi

cargo test --quiet -p irlgrid --test doc_anchors
echo "book built in $out; every link checked"

#!/usr/bin/env python3
"""Tests of tools/handler_length.py on a tiny fake routes directory built in
a temp dir: it must fail (exit 1) on a `pub async fn` handler over 40
lines, and pass (exit 0) on short ones, including long private helpers,
signatures over several lines and braces in strings and comments.
Run: python3 tools/test_handler_length.py"""
import pathlib
import subprocess
import sys
import tempfile
import textwrap
import unittest

CHECKER = pathlib.Path(__file__).resolve().parent / "handler_length.py"


def run_on(files):
    """Writes `files` ({path: text}) under a fresh root and runs the
    checker there: (exit status, output)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        for rel, text in files.items():
            p = root / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(textwrap.dedent(text))
        r = subprocess.run([sys.executable, str(CHECKER), str(root)],
                           capture_output=True, text=True, check=False)
        return r.returncode, r.stdout + r.stderr


def handler(name, body_lines, public=True):
    """A handler whose `fn` line to closing brace spans 5 + body_lines
    lines."""
    vis = "pub " if public else ""
    body = "\n".join(f"    let x{i} = \"{{ not a brace }}\"; // }}" for i in range(body_lines))
    return (f"{vis}async fn {name}(\n    s: State<AppState>,\n) -> Result<(), E> {{\n"
            f"{body}\n    Ok(())\n}}\n")


class HandlerLength(unittest.TestCase):
    def test_short_handlers_and_long_private_helpers_pass(self):
        code, out = run_on({
            "coordinator/src/routes/jobs.rs": handler("lease", 35)
            + handler("helper", 200, public=False)
            + "pub async fn declared(x: Vec<u8>) -> u8;\n",
        })
        self.assertEqual(code, 0, out)
        self.assertIn("0 handlers over 40 lines of 1", out)
        self.assertIn("jobs.rs::lease, 40 lines", out)

    def test_a_long_handler_fails(self):
        code, out = run_on({
            "coordinator/src/routes/searches.rs": handler("ok", 10) + handler("score", 36),
        })
        self.assertEqual(code, 1, out)
        self.assertIn("handler score is 41 lines (limit 40)", out)
        self.assertNotIn("handler ok", out)

    def test_no_routes_directory_is_a_usage_error(self):
        code, _ = run_on({"README.md": "nothing here\n"})
        self.assertEqual(code, 2)


if __name__ == "__main__":
    unittest.main()

#!/usr/bin/env python3
"""Tests of tools/handler_length.py on a tiny fake routes directory built in
a temp dir: it must fail (exit 1) on a `pub async fn` handler over 40
lines, and pass (exit 0) on short ones, including long private helpers,
signatures over several lines and braces in strings and comments.
Run: python3 tools/test_handler_length.py"""
import pathlib
import sys
import unittest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent / "lib"))
from fake_tree import run_checker_on  # noqa: E402

CHECKER = pathlib.Path(__file__).resolve().parent / "handler_length.py"


def run_on(files):
    """Runs the checker on a fake tree of `files`: (exit status, output)."""
    return run_checker_on(CHECKER, files)


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

"""Runs one of our source checkers (tools/import_graph.py,
tools/handler_length.py) on a tiny fake tree, for their tests
(tools/test_*.py)."""
import pathlib
import subprocess
import sys
import tempfile
import textwrap


def run_checker_on(checker: pathlib.Path, files: dict) -> tuple:
    """Writes `files` ({path: text}, dedented) under a fresh root and runs
    `checker` there: (exit status, output)."""
    with tempfile.TemporaryDirectory() as tmp:
        root = pathlib.Path(tmp)
        for rel, text in files.items():
            p = root / rel
            p.parent.mkdir(parents=True, exist_ok=True)
            p.write_text(textwrap.dedent(text))
        r = subprocess.run([sys.executable, str(checker), str(root)],
                           capture_output=True, text=True, check=False)
        return r.returncode, r.stdout + r.stderr

#!/usr/bin/env python3
"""Tests of tools/import_graph.py on tiny fake workspaces built in a temp
dir: it must fail (exit 1) on a circle between files and on a science ->
wire import, and pass (exit 0) on clean crates, including the cases that
look like imports but are not. Run: python3 tools/test_import_graph.py"""
import pathlib
import sys
import textwrap
import unittest

sys.path.insert(0, str(pathlib.Path(__file__).resolve().parent / "lib"))
from fake_tree import run_checker_on  # noqa: E402

CHECKER = pathlib.Path(__file__).resolve().parent / "import_graph.py"


def run_on(files):
    """Runs the checker on a fake tree of `files`: (exit status, output)."""
    return run_checker_on(CHECKER, files)


def crate(name, files):
    """A crate `name` in the workspace: its Cargo.toml and src files."""
    out = {f"{name}/Cargo.toml": f'[package]\nname = "{name}"\nversion = "0.1.0"\n'}
    out.update({f"{name}/src/{k}": v for k, v in files.items()})
    return out


CLEAN_SHARED = {
    "lib.rs": """
        pub mod analysis;
        pub mod api;
        pub mod sim;
    """,
    "sim/mod.rs": """
        mod dynamics;
        pub use dynamics::Model;
        /// Errors of the simulator.
        pub struct SimError;
    """,
    "sim/dynamics.rs": """
        use super::SimError; // a child naming its parent's item: its namespace
        pub struct Model;
        pub fn check() -> Result<(), SimError> { Ok(()) }
    """,
    "analysis/mod.rs": """
        mod points;
        pub mod report;
        pub use points::point_label;
    """,
    "analysis/points.rs": """
        pub fn point_label() -> String { String::new() }
    """,
    "analysis/report.rs": """
        use crate::sim::{self, Model};
        pub fn describe(_m: &Model) -> String { super::point_label() }
        pub fn build() { let _ = sim::Model; }
    """,
    "api.rs": """
        //! The wire module may import the science core.
        pub use crate::analysis::point_label;
        use crate::analysis::report::{build, describe};
        pub fn wire() { build(); let _ = describe; }
    """,
}


class ImportGraph(unittest.TestCase):
    def test_clean_workspace_passes(self):
        files = crate("shared", CLEAN_SHARED)
        files.update(crate("app", {"main.rs": "mod cli;\nfn main() { cli::go(); }\n",
                                   "cli.rs": "pub fn go() {}\n"}))
        code, out = run_on(files)
        self.assertEqual(code, 0, out)
        self.assertIn("no circle", out)

    def test_circle_between_two_files_fails(self):
        code, out = run_on(crate("app", {
            "lib.rs": "pub mod client;\npub mod run;\n",
            "client.rs": "pub fn submit() {}\npub fn show() { crate::run::table(); }\n",
            "run.rs": "use super::client::submit;\npub fn table() {}\npub fn go() { submit(); }\n",
        }))
        self.assertEqual(code, 1, out)
        self.assertIn("circle: app/src/client.rs <-> app/src/run.rs", out)

    def test_circle_through_grouped_use_and_reexport_fails(self):
        # a.rs names Thing through the facade m/mod.rs, which re-exports it
        # from m/inner.rs; inner.rs names a.rs's helper by a nested group.
        code, out = run_on(crate("app", {
            "lib.rs": "pub mod a;\npub mod m;\n",
            "a.rs": "use crate::m::{self as facade, Thing};\n"
                    "pub fn helper() {}\npub fn f(_: Thing) { facade::other(); }\n",
            "m/mod.rs": "mod inner;\npub use inner::Thing;\npub fn other() {}\n",
            "m/inner.rs": "use crate::{a::{helper}, m};\npub struct Thing;\n"
                          "pub fn g() { helper(); m::other(); }\n",
        }))
        self.assertEqual(code, 1, out)
        self.assertIn("circle: app/src/a.rs <-> app/src/m/inner.rs", out)

    def test_circle_by_inline_path_through_use_bound_module_fails(self):
        code, out = run_on(crate("app", {
            "lib.rs": "mod x;\nmod y;\n",
            "x.rs": "use crate::y;\npub struct X;\nfn f() { let _ = y::Y; }\n",
            "y.rs": "pub struct Y;\nfn g() { let _ = super::x::X; }\n",
        }))
        self.assertEqual(code, 1, out)
        self.assertIn("circle: app/src/x.rs <-> app/src/y.rs", out)

    def test_science_importing_the_wire_module_fails(self):
        files = dict(CLEAN_SHARED)
        files["api.rs"] = "pub struct JobSpec;\n"
        files["sim/dynamics.rs"] = (
            "use super::SimError;\npub struct Model;\n"
            "pub fn spec() -> crate::api::JobSpec { crate::api::JobSpec }\n")
        code, out = run_on(crate("shared", files))
        self.assertEqual(code, 1, out)
        self.assertIn("layer: shared/src/sim/dynamics.rs -> shared/src/api.rs", out)
        self.assertNotIn("circle:", out)

    def test_science_naming_a_reexport_of_the_wire_module_fails(self):
        # The item is the analysis's own, but the path goes through `api`.
        files = dict(CLEAN_SHARED)
        files["analysis/report.rs"] = (
            "pub fn build() {}\npub fn describe() -> String { crate::api::point_label() }\n")
        files["api.rs"] = "pub use crate::analysis::point_label;\n"
        code, out = run_on(crate("shared", files))
        self.assertEqual(code, 1, out)
        self.assertIn("layer: shared/src/analysis/report.rs -> shared/src/api.rs", out)

    def test_science_importing_a_wire_submodule_by_grouped_use_fails(self):
        files = dict(CLEAN_SHARED)
        files["lib.rs"] = "pub mod analysis;\npub mod api;\npub mod sim;\npub mod sample;\n"
        files["api.rs"] = "pub mod types;\n"
        files["api/types.rs"] = "pub struct Lease;\n"
        files["sample.rs"] = "use crate::{sim::Model, api::types::Lease};\npub fn f(_: Lease, _: Model) {}\n"
        code, out = run_on(crate("shared", files))
        self.assertEqual(code, 1, out)
        self.assertIn("layer: shared/src/sample.rs -> shared/src/api/types.rs", out)

    def test_test_code_comments_and_strings_are_no_imports(self):
        code, out = run_on(crate("app", {
            "lib.rs": "pub mod a;\npub mod b;\n",
            "a.rs": "pub fn f() { crate::b::g(); }\n",
            "b.rs": textwrap.dedent("""\
                pub fn g() {
                    // crate::a::f();
                    /* crate::a::f(); /* nested */ crate::a::f(); */
                    let _ = "crate::a::f()";
                    let _ = r#"use crate::a::f;"#;
                    let _ = '"';
                }
                #[cfg(test)]
                #[allow(unused)]
                mod tests {
                    use crate::a::f;
                    fn t() { f(); }
                }
                """),
        }))
        self.assertEqual(code, 0, out)


if __name__ == "__main__":
    unittest.main(verbosity=2)

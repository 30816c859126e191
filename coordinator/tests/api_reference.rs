//! The committed API reference (`docs/api-reference.md`) is what the
//! OpenAPI document renders to now. When the API changes, regenerate it:
//!
//!     IRLGRID_BLESS=1 cargo test -p coordinator --test api_reference

use std::path::PathBuf;

use coordinator::api_reference::{render, REGENERATE};

fn page_path() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../docs/api-reference.md")
}

#[test]
fn the_committed_api_reference_is_current() {
    let want = render(&coordinator::openapi::document());
    let path = page_path();
    if std::env::var("IRLGRID_BLESS").is_ok_and(|v| v == "1") {
        std::fs::write(&path, &want).expect("writing docs/api-reference.md");
        eprintln!("wrote {}", path.display());
        return;
    }
    let have = std::fs::read_to_string(&path).unwrap_or_default();
    if have != want {
        let first = have
            .lines()
            .zip(want.lines())
            .position(|(a, b)| a != b)
            .unwrap_or_else(|| have.lines().count().min(want.lines().count()));
        panic!(
            "docs/api-reference.md is stale (first difference at line {}: have {:?}, want {:?}); \
             regenerate it with `{REGENERATE}` and commit it",
            first + 1,
            have.lines().nth(first).unwrap_or("<end>"),
            want.lines().nth(first).unwrap_or("<end>"),
        );
    }
}

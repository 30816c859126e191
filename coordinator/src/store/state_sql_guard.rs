//! The coordinator's SQL never spells a stored state: a statement that
//! names a job, search or refinement state binds its enum's text
//! ([`JobState::as_str`], [`SearchState::as_str`], [`RefineState::as_str`])
//! as a parameter, so each state has one spelling, in Rust.
//!
//! The scan below reads every source file of `coordinator/src` and fails
//! on a string literal that reads as SQL (a statement, or a fragment that
//! names the `status` or `refine_state` column, as a constant holding part
//! of a statement does) and holds a quoted state word such as `'leased'`.
//! The words are the `as_str` values of the enums' `ALL` lists, so a new
//! state is guarded as soon as it is listed. The migrations are exempt:
//! their check constraints and triggers must spell the states.

use std::path::{Path, PathBuf};

use shared::api::{JobState, SearchState};

use super::states::RefineState;

/// Every stored state word, from the enums themselves.
fn state_words() -> Vec<&'static str> {
    let mut words: Vec<&'static str> = JobState::ALL
        .iter()
        .map(|s| s.as_str())
        .chain(SearchState::ALL.iter().map(|s| s.as_str()))
        .chain(RefineState::ALL.iter().map(|s| s.as_str()))
        .collect();
    words.sort_unstable();
    words.dedup();
    words
}

/// Whether a literal reads as SQL or as a piece of a statement about
/// states.
fn reads_as_sql(s: &str) -> bool {
    let l = s.to_ascii_lowercase();
    [
        "select ",
        "insert ",
        "update ",
        "delete ",
        "where ",
        "case when",
        "status",
        "refine_state",
    ]
    .iter()
    .any(|w| l.contains(w))
}

/// The string literal starting at `s` (a `"` or `r#"`), and its length in
/// the source.
fn literal(s: &str) -> Option<(String, usize)> {
    if let Some(rest) = s.strip_prefix('"') {
        let mut out = String::new();
        let mut chars = rest.char_indices();
        while let Some((i, c)) = chars.next() {
            match c {
                '\\' => {
                    if let Some((_, n)) = chars.next() {
                        out.push(n);
                    }
                }
                '"' => return Some((out, i + 2)),
                c => out.push(c),
            }
        }
        return None;
    }
    let hashes = s
        .strip_prefix('r')?
        .chars()
        .take_while(|c| *c == '#')
        .count();
    let open = format!("r{}\"", "#".repeat(hashes));
    let close = format!("\"{}", "#".repeat(hashes));
    let body = s.strip_prefix(&open)?;
    let end = body.find(&close)?;
    Some((body[..end].to_string(), open.len() + end + close.len()))
}

/// Every string literal of a source text (start, text), skipping comments
/// and character literals.
fn string_literals(src: &str) -> Vec<(usize, String)> {
    let b = src.as_bytes();
    let mut out = Vec::new();
    let mut i = 0;
    while i < b.len() {
        match b[i] {
            b'/' if b.get(i + 1) == Some(&b'/') => {
                i = src[i..].find('\n').map_or(b.len(), |k| i + k);
            }
            b'/' if b.get(i + 1) == Some(&b'*') => {
                i = src[i..].find("*/").map_or(b.len(), |k| i + k + 2);
            }
            b'\'' => {
                // A character literal ('x', '\n', '\u{..}'), else a lifetime.
                if b.get(i + 1) == Some(&b'\\') {
                    i = src[i + 2..].find('\'').map_or(b.len(), |k| i + 2 + k + 1);
                } else if b.get(i + 2) == Some(&b'\'') {
                    i += 3;
                } else {
                    i += 1;
                }
            }
            b'"' | b'r' if src.is_char_boundary(i) => {
                let raw_start = b[i] == b'r'
                    && (i == 0 || !(b[i - 1].is_ascii_alphanumeric() || b[i - 1] == b'_'));
                if b[i] == b'"' || raw_start {
                    if let Some((text, len)) = literal(&src[i..]) {
                        out.push((i, text));
                        i += len;
                        continue;
                    }
                }
                i += 1;
            }
            _ => i += 1,
        }
    }
    out
}

/// The quoted state words in the SQL literals of one source text, as
/// (line, what).
fn spelled_states(src: &str, words: &[&str]) -> Vec<(usize, String)> {
    let mut bad = Vec::new();
    for (at, text) in string_literals(src) {
        if !reads_as_sql(&text) {
            continue;
        }
        for w in words {
            if text.contains(&format!("'{w}'")) {
                let line = src[..at].matches('\n').count() + 1;
                bad.push((line, format!("state '{w}' spelled in SQL {text:?}")));
            }
        }
    }
    bad
}

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for e in std::fs::read_dir(dir).unwrap() {
        let p = e.unwrap().path();
        if p.is_dir() {
            rust_files(&p, out);
        } else if p.extension().is_some_and(|x| x == "rs") {
            out.push(p);
        }
    }
}

#[test]
fn no_sql_of_the_coordinator_spells_a_state() {
    let src_dir = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut files = Vec::new();
    rust_files(&src_dir, &mut files);
    assert!(files.len() > 20, "found only {} files", files.len());
    let words = state_words();
    let (mut sql_literals, mut bad) = (0, Vec::new());
    for f in &files {
        let src = std::fs::read_to_string(f).unwrap();
        sql_literals += string_literals(&src)
            .iter()
            .filter(|(_, t)| reads_as_sql(t))
            .count();
        for (line, what) in spelled_states(&src, &words) {
            let name = f.strip_prefix(&src_dir).unwrap().display();
            bad.push(format!("coordinator/src/{name}:{line}: {what}"));
        }
    }
    // The scan saw the store's statements (it is not vacuous).
    assert!(sql_literals > 50, "only {sql_literals} SQL literals seen");
    assert!(
        bad.is_empty(),
        "bind the state's `as_str()` instead of spelling it:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_state_scanner_catches_a_spelled_state() {
    // `@` stands for each state word in turn (spelled here, the templates
    // would trip the scan of this very file).
    let bad = [
        r#"sqlx::query("select id from jobs where search_id = ?1 and status = '@'")"#,
        r#"let sql = "... where status = '@'";"#,
        r##"tx.prepare_cached(r#"update jobs set status = '@' where id = ?1"#)"##,
        r#"const COLS: &str = "j.id, case when j.status = '@' then 1 end";"#,
        r#"tx.prepare_cached("update searches set refine_state = '@' where id = ?1")"#,
        r#""select 1 from jobs where status in (?2, '@')""#,
    ];
    let good = [
        r#"sqlx::query("select id from jobs where status = ?2").bind(JobState::Leased.as_str())"#,
        r#"tx.prepare_cached("update jobs set status = ?2 where id = ?1 and status in (?3, ?4)")"#,
        r#"// where status = '@' (a comment)"#,
        r#"/* update jobs set status = '@' */"#,
        r#"format!("job {job_id} is '@'")"#,
        r#"sqlx::query("select id from jobs where worker_id = '@-1'")"#,
    ];
    let words = state_words();
    assert!(words.contains(&"leased") && words.contains(&"pending"));
    for w in &words {
        for b in bad {
            let b = b.replace('@', w);
            assert!(!spelled_states(&b, &words).is_empty(), "not caught: {b}");
        }
        for g in good {
            let g = g.replace('@', w);
            let found = spelled_states(&g, &words);
            assert!(found.is_empty(), "false alarm on {g}: {found:?}");
        }
    }
}

/// The strings of a JSON Schema's `enum` and `const` keywords.
fn schema_strings(v: &serde_json::Value, out: &mut Vec<String>) {
    match v {
        serde_json::Value::Object(m) => {
            for (k, x) in m {
                match (k.as_str(), x) {
                    ("const", serde_json::Value::String(s)) => out.push(s.clone()),
                    ("enum", serde_json::Value::Array(a)) => {
                        out.extend(a.iter().filter_map(|s| s.as_str().map(String::from)))
                    }
                    _ => schema_strings(x, out),
                }
            }
        }
        serde_json::Value::Array(a) => a.iter().for_each(|x| schema_strings(x, out)),
        _ => {}
    }
}

/// `ALL` of the wire enums lists every variant: their JSON Schemas (derived
/// from the enum definitions) name the same words, so the scan above
/// cannot miss a state added to the enum but not to `ALL`.
#[test]
fn all_lists_every_wire_state() {
    fn words_of(schema: schemars::Schema) -> Vec<String> {
        let mut out = Vec::new();
        schema_strings(schema.as_value(), &mut out);
        out.sort();
        out
    }
    let sorted = |w: Vec<&str>| {
        let mut w: Vec<String> = w.into_iter().map(String::from).collect();
        w.sort();
        w
    };
    assert_eq!(
        words_of(schemars::schema_for!(JobState)),
        sorted(JobState::ALL.iter().map(|s| s.as_str()).collect()),
        "JobState::ALL"
    );
    assert_eq!(
        words_of(schemars::schema_for!(SearchState)),
        sorted(SearchState::ALL.iter().map(|s| s.as_str()).collect()),
        "SearchState::ALL"
    );
}

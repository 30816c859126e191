//! SQL is always parameterized: a scan of the workspace's Rust
//! sources that fails when a statement could carry a value spliced into
//! its text rather than bound.
//!
//! Rules:
//! 1. A string built with `format!`, `write!`, `concat!`, `push_str` or
//!    `+` whose text looks like SQL may interpolate only named constants
//!    (`{JOB_COLUMNS}`, upper case): no positional `{}` and no variable.
//! 2. The statement given to `sqlx::query*`, `prepare`, `prepare_cached`,
//!    `query_row`, `execute_batch` (and rusqlite's `execute` with a string)
//!    is a string literal, or a local `sql` that rule 1 has checked.
//!
//! 3. A state (`'leased'`, `'running'`, ...) is never spelled in the
//!    coordinator's SQL: it is bound from its enum (see the last section).
//!
//! The scanner's own unit tests below show that it catches the usual ways
//! of splicing values and of spelling states.

use std::path::{Path, PathBuf};

use coordinator::store::states::RefineState;
use shared::api::{JobState, SearchState};

/// SQL words that mark a string as a statement.
fn looks_like_sql(s: &str) -> bool {
    let l = s.to_ascii_lowercase();
    let words = [
        "select ",
        "insert into",
        "update ",
        "delete from",
        " where ",
        "values (",
        "pragma ",
        "vacuum",
        "order by",
        " limit ",
    ];
    words.iter().any(|w| l.contains(w))
        && (l.contains("select ")
            || l.contains("insert ")
            || l.contains("update ")
            || l.contains("delete ")
            || l.contains("pragma ")
            || l.contains("vacuum"))
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

/// Whether every `{...}` in a format string names an upper-case constant.
fn only_constant_placeholders(fmt: &str) -> bool {
    let mut rest = fmt.replace("{{", "").replace("}}", "");
    while let Some(i) = rest.find('{') {
        let Some(j) = rest[i..].find('}') else {
            return false;
        };
        let name = rest[i + 1..i + j].split(':').next().unwrap_or("");
        let constant = !name.is_empty()
            && name.chars().next().is_some_and(|c| c.is_ascii_uppercase())
            && name
                .chars()
                .all(|c| c.is_ascii_uppercase() || c.is_ascii_digit() || c == '_');
        if !constant {
            return false;
        }
        rest = rest[i + j + 1..].to_string();
    }
    true
}

/// Every string literal of a source text (start, text, source length),
/// skipping comments and character literals.
fn string_literals(src: &str) -> Vec<(usize, String, usize)> {
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
                        out.push((i, text, len));
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

/// The first non-blank text after `at`.
fn after(src: &str, at: usize) -> &str {
    src[at..].trim_start()
}

/// Offending spots of one source text: (line, what).
fn scan(src: &str) -> Vec<(usize, String)> {
    let line_of = |i: usize| src[..i].matches('\n').count() + 1;
    let mut bad = Vec::new();
    // Rule 1: building SQL text.
    for builder in ["format!(", "write!(", "writeln!(", "concat!(", "push_str("] {
        let mut from = 0;
        while let Some(k) = src[from..].find(builder) {
            let at = from + k + builder.len();
            from = at;
            let mut arg = after(src, at);
            if builder.starts_with("write") {
                // Skip the destination argument.
                match arg.find(',') {
                    Some(c) => arg = arg[c + 1..].trim_start(),
                    None => continue,
                }
            }
            let arg = arg.strip_prefix('&').unwrap_or(arg);
            let Some((text, len)) = literal(arg) else {
                continue;
            };
            if !looks_like_sql(&text) {
                continue;
            }
            let tail = arg[len..].trim_start();
            let positional_args = builder != "push_str(" && tail.starts_with(',');
            let spliced = match builder {
                "concat!(" => positional_args,
                "push_str(" => false,
                _ => positional_args || !only_constant_placeholders(&text),
            };
            if spliced {
                bad.push((
                    line_of(at),
                    format!("{builder} builds SQL with a value: {text:?}"),
                ));
            }
        }
    }
    // `"select ..." + x`: a SQL literal concatenated with something.
    for (at, text, len) in string_literals(src) {
        let tail = src[at + len..].trim_start();
        let tail = [".to_string()", ".to_owned()", ")"]
            .iter()
            .find_map(|p| tail.strip_prefix(p))
            .unwrap_or(tail)
            .trim_start();
        if looks_like_sql(&text) && tail.starts_with('+') {
            bad.push((line_of(at), format!("SQL concatenated with +: {text:?}")));
        }
    }
    // Rule 2: what statements are run with.
    for call in [
        "sqlx::query(",
        "sqlx::query_scalar(",
        "sqlx::query_as(",
        "query_with(",
        ".prepare_cached(",
        ".prepare(",
        ".query_row(",
        ".execute_batch(",
        ".execute(",
    ] {
        let mut from = 0;
        while let Some(k) = src[from..].find(call) {
            let at = from + k + call.len();
            from = at;
            let arg = after(src, at);
            if literal(arg).is_some() {
                continue;
            }
            let ident: String = arg
                .trim_start_matches('&')
                .chars()
                .take_while(|c| c.is_alphanumeric() || *c == '_' || *c == '.' || *c == '!')
                .collect();
            let dynamic_sql = ident == "sql"
                || ident.ends_with("sql")
                || ident.contains("query")
                || ident.starts_with("format!")
                || ident.starts_with("concat!");
            match call {
                // These take the statement first: anything but a literal
                // must be a `sql` variable (built under rule 1).
                "sqlx::query("
                | "sqlx::query_scalar("
                | "sqlx::query_as("
                | ".prepare_cached("
                | ".prepare("
                | ".execute_batch(" => {
                    if ident != "sql" {
                        bad.push((
                            line_of(at),
                            format!("{call} with a non-literal statement {ident:?}"),
                        ));
                    }
                }
                // These also take executors or parameters first; only a
                // statement-like argument is suspicious.
                _ => {
                    if dynamic_sql && ident != "sql" {
                        bad.push((
                            line_of(at),
                            format!("{call} with a built statement {ident:?}"),
                        ));
                    }
                }
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
fn every_sql_statement_in_the_workspace_is_parameterized() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let mut files = Vec::new();
    for d in ["coordinator/src", "worker/src", "shared/src", "src"] {
        rust_files(&root.join(d), &mut files);
    }
    assert!(files.len() > 20, "found only {} files", files.len());
    let mut statements = 0;
    let mut bad = Vec::new();
    for f in &files {
        let src = std::fs::read_to_string(f).unwrap();
        statements += src.matches("sqlx::query").count() + src.matches("prepare_cached(").count();
        for (line, what) in scan(&src) {
            bad.push(format!(
                "{}:{line}: {what}",
                f.strip_prefix(root).unwrap().display()
            ));
        }
    }
    // The scan saw the coordinator's statements (it is not vacuous).
    assert!(statements > 30, "only {statements} statements seen");
    assert!(bad.is_empty(), "SQL built from values:\n{}", bad.join("\n"));
}

/// The coordinator's SQL lives in one place: its `store` module. Every
/// other source file of the coordinator is free of SQL in string literals
/// and of SQL driver calls, so a statement cannot slip into a route or the
/// dashboard unseen.
#[test]
fn no_sql_outside_the_coordinator_store() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR")).parent().unwrap();
    let store = root.join("coordinator/src/store");
    let mut files = Vec::new();
    rust_files(&root.join("coordinator/src"), &mut files);
    let mut store_files = 0;
    let mut bad = Vec::new();
    for f in &files {
        if f.starts_with(&store) {
            store_files += 1;
            continue;
        }
        let src = std::fs::read_to_string(f).unwrap();
        let at = |i: usize| src[..i].matches('\n').count() + 1;
        let name = f.strip_prefix(root).unwrap().display().to_string();
        for (i, text, _) in string_literals(&src) {
            if looks_like_sql(&text) {
                bad.push(format!("{name}:{}: SQL text {text:?}", at(i)));
            }
        }
        for call in [
            "sqlx::query",
            "prepare_cached(",
            ".prepare(",
            ".execute_batch(",
        ] {
            if let Some(i) = src.find(call) {
                bad.push(format!("{name}:{}: SQL driver call {call}", at(i)));
            }
        }
    }
    assert!(store_files >= 4, "found only {store_files} store files");
    assert!(
        bad.is_empty(),
        "SQL outside coordinator/src/store:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_scanner_catches_spliced_values() {
    let bad = [
        r#"let sql = format!("select * from jobs where id = {}", id);"#,
        r#"let sql = format!("select * from jobs where id = {id}");"#,
        r#"let sql = format!("delete from jobs where search_id = '{search_id}'");"#,
        r#"let q = "select * from jobs where id = ".to_string() + &id;"#,
        r#"sqlx::query(&format!("update jobs set x = 1 where id = {id}"))"#,
        r#"sqlx::query(&q).bind(1)"#,
        r#"tx.prepare_cached(stmt)"#,
        r#"conn.execute(&format!("insert into t values ({v})"), [])"#,
        r#"write!(s, "select x from t where y = {}", y)"#,
        r#"tx.execute_batch(&query_text)"#,
    ];
    for b in bad {
        assert!(!scan(b).is_empty(), "not caught: {b}");
    }
    let good = [
        r#"sqlx::query("select * from jobs where id = ?1").bind(id)"#,
        r#"let sql = format!("select {JOB_COLUMNS} from jobs j where j.id = ?1"); sqlx::query(&sql)"#,
        r##"tx.prepare_cached(r#"update jobs set a = ?1 where id = ?2"#)"##,
        r#"format!("no job with id {job_id}")"#,
        r#"st.execute(params![job_id])"#,
        r#"q.execute(&db.write).await"#,
        r#"tx.query_row("select status from jobs where id = ?1", params![id], |r| r.get(0))"#,
    ];
    for g in good {
        assert!(scan(g).is_empty(), "false alarm on {g}: {:?}", scan(g));
    }
}

// ------------------------------------------------------------------
// States are bound, never spelled: a statement that names a job, search
// or refinement state binds its enum's text (`as_str`) as a parameter, so
// each state has one spelling, in Rust. The scan fails on a string literal
// of coordinator/src that reads as SQL (a statement, or a fragment naming
// the `status` or `refine_state` column) and holds a quoted state word
// such as `'leased'`. The words come from the enums' `ALL` lists, and a
// test below pins those lists to the enums' derived JSON Schemas, so a new
// state is guarded as soon as it exists. Migrations are exempt: their
// check constraints and triggers must spell the states.

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
fn reads_as_state_sql(s: &str) -> bool {
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

/// The quoted state words in the SQL literals of one source text, as
/// (line, what).
fn spelled_states(src: &str, words: &[&str]) -> Vec<(usize, String)> {
    let mut bad = Vec::new();
    for (at, text, _) in string_literals(src) {
        if !reads_as_state_sql(&text) {
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
            .filter(|(_, t, _)| reads_as_state_sql(t))
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

//! The repository's cross-references hold: every `<path>.md#<anchor>` cited
//! in a tracked text file (code comments such as `docs/science.md#reward`,
//! markdown links such as `[x](science.md#sampling)`) names a tracked
//! markdown document that has a heading with that GitHub-style slug, and
//! every in-page link `](#anchor)` of a markdown file names one of its own
//! headings. Also, nothing refers to the old out-of-repository spec.
//!
//! Resolution of a cited path: `docs/...` and every path cited from a
//! non-markdown file are relative to the repository root; other paths in a
//! markdown file are relative to that file's directory, as GitHub resolves
//! links. URLs (`https://.../README.md#x`) and absolute paths are skipped, and
//! so are references without an anchor (a bare `docs/inference.md` may name a
//! document that another branch adds).
//!
//! Headings are ATX headings (`#` to `######`) outside fenced code blocks.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

/// This file, which necessarily contains the strings it forbids and
/// made-up references for its own negative tests.
const SELF_PATH: &str = "tests/doc_anchors.rs";

/// GitHub's heading slug: lower case; letters, digits, `-` and `_` kept;
/// each space becomes `-`; everything else (punctuation, backticks) dropped.
fn slug(heading: &str) -> String {
    heading
        .trim()
        .to_lowercase()
        .chars()
        .filter_map(|c| match c {
            ' ' => Some('-'),
            '-' | '_' => Some(c),
            c if c.is_alphanumeric() => Some(c),
            _ => None,
        })
        .collect()
}

/// The heading texts of a markdown document, in order.
fn headings(markdown: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fence: Option<&str> = None;
    for line in markdown.lines() {
        let trimmed = line.trim_start();
        let indent = line.len() - trimmed.len();
        for marker in ["```", "~~~"] {
            if trimmed.starts_with(marker) {
                fence = match fence {
                    None => Some(marker),
                    Some(open) if open == marker => None,
                    other => other,
                };
            }
        }
        if fence.is_some() || indent > 3 || !trimmed.starts_with('#') {
            continue;
        }
        let level = trimmed.chars().take_while(|&c| c == '#').count();
        let rest = &trimmed[level..];
        if level > 6 || !(rest.is_empty() || rest.starts_with(' ') || rest.starts_with('\t')) {
            continue;
        }
        // An optional closing sequence of `#`s after a space.
        let text = rest.trim();
        let text = match text.trim_end_matches('#') {
            t if t.len() < text.len() && (t.is_empty() || t.ends_with(' ')) => t.trim_end(),
            _ => text,
        };
        out.push(text.to_string());
    }
    out
}

/// The anchors a document offers: heading slugs, a repeated slug getting
/// `-1`, `-2`, ... as on GitHub.
fn anchors(markdown: &str) -> BTreeSet<String> {
    let mut seen: BTreeMap<String, usize> = BTreeMap::new();
    let mut out = BTreeSet::new();
    for h in headings(markdown) {
        let base = slug(&h);
        let n = seen.entry(base.clone()).or_insert(0);
        out.insert(if *n == 0 {
            base.clone()
        } else {
            format!("{base}-{n}")
        });
        *n += 1;
    }
    out
}

/// One cross-reference found in a file.
#[derive(Debug, PartialEq)]
struct Reference {
    /// 1-based line of the reference.
    line: usize,
    /// The target document as written (empty for an in-page `](#anchor)`).
    path: String,
    /// The anchor after `#`.
    anchor: String,
}

fn is_path_char(c: char) -> bool {
    c.is_ascii_alphanumeric() || matches!(c, '_' | '-' | '.' | '/')
}

fn is_anchor_char(c: char) -> bool {
    c.is_alphanumeric() || matches!(c, '_' | '-')
}

/// Every `<path>.md#<anchor>` in `text`, and in markdown files every
/// `](#<anchor>)`. Skips URLs, absolute paths and empty anchors.
fn references(text: &str, markdown: bool) -> Vec<Reference> {
    let mut out = Vec::new();
    for (i, line) in text.lines().enumerate() {
        let chars: Vec<char> = line.chars().collect();
        let mut k = 0;
        while k + 4 <= chars.len() {
            let cross = chars[k..k + 4] == ['.', 'm', 'd', '#'];
            let local = markdown && k + 3 <= chars.len() && chars[k..k + 3] == [']', '(', '#'];
            if !cross && !local {
                k += 1;
                continue;
            }
            let (path, after) = if cross {
                let mut start = k;
                while start > 0 && is_path_char(chars[start - 1]) {
                    start -= 1;
                }
                let path: String = chars[start..k + 3].iter().collect();
                let url = start > 0 && chars[start - 1] == ':';
                let stem_empty = start == k;
                if url || stem_empty || path.starts_with('/') {
                    k += 4;
                    continue;
                }
                (path, k + 4)
            } else {
                (String::new(), k + 3)
            };
            let mut end = after;
            while end < chars.len() && is_anchor_char(chars[end]) {
                end += 1;
            }
            if end > after {
                out.push(Reference {
                    line: i + 1,
                    path,
                    anchor: chars[after..end].iter().collect(),
                });
            }
            k = end.max(k + 1);
        }
    }
    out
}

/// `base` joined with the relative `rel`, `.` and `..` resolved; `None` if
/// it climbs out of the repository.
fn join(base: &str, rel: &str) -> Option<String> {
    let mut parts: Vec<&str> = base.split('/').filter(|p| !p.is_empty()).collect();
    for p in rel.split('/') {
        match p {
            "" | "." => {}
            ".." => {
                parts.pop()?;
            }
            p => parts.push(p),
        }
    }
    Some(parts.join("/"))
}

/// The repository path a reference in `from` points at.
fn resolve(from: &str, cited: &str) -> Option<String> {
    if cited.is_empty() {
        return Some(from.to_string());
    }
    let from_markdown = from.ends_with(".md");
    if cited.starts_with("docs/") || !from_markdown {
        return join("", cited);
    }
    let dir = Path::new(from)
        .parent()
        .and_then(Path::to_str)
        .unwrap_or("");
    join(dir, cited)
}

/// Every broken reference among `files` (repository path -> text), one
/// message each. Targets are looked up in `files` too.
fn broken_references(files: &BTreeMap<String, String>) -> Vec<String> {
    let mut cache: BTreeMap<String, BTreeSet<String>> = BTreeMap::new();
    let mut errors = Vec::new();
    for (path, text) in files {
        if path == SELF_PATH {
            continue;
        }
        for r in references(text, path.ends_with(".md")) {
            let at = format!("{path}:{}", r.line);
            let shown = if r.path.is_empty() {
                format!("#{}", r.anchor)
            } else {
                format!("{}#{}", r.path, r.anchor)
            };
            let Some(target) = resolve(path, &r.path) else {
                errors.push(format!("{at}: {shown} points outside the repository"));
                continue;
            };
            let Some(doc) = files.get(&target) else {
                errors.push(format!("{at}: {shown}: no tracked file {target}"));
                continue;
            };
            let offered = cache.entry(target.clone()).or_insert_with(|| anchors(doc));
            if !offered.contains(&r.anchor) {
                errors.push(format!(
                    "{at}: {shown}: {target} has no heading with slug {:?}",
                    r.anchor
                ));
            }
        }
    }
    errors
}

/// Files that mention the out-of-repository spec.
fn spec_citations(files: &BTreeMap<String, String>) -> Vec<String> {
    // Spelled in pieces so that this file does not match itself.
    let needles = [format!("shared/{}", "SPEC"), format!("SPEC {}", '§')];
    let mut out = Vec::new();
    for (path, text) in files {
        if path == SELF_PATH {
            continue;
        }
        for (i, line) in text.lines().enumerate() {
            if let Some(n) = needles.iter().find(|n| line.contains(n.as_str())) {
                out.push(format!("{path}:{}: cites {n:?}", i + 1));
            }
        }
    }
    out
}

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

/// Tracked files by `git ls-files`; without git (an exported tarball), every
/// file under the root except `target/` and `.git/`.
fn tracked_paths(root: &Path) -> Vec<String> {
    let git = Command::new("git")
        .args(["ls-files", "-z"])
        .current_dir(root)
        .output();
    if let Ok(out) = git {
        if out.status.success() && !out.stdout.is_empty() {
            return String::from_utf8_lossy(&out.stdout)
                .split('\0')
                .filter(|p| !p.is_empty())
                .map(str::to_string)
                .collect();
        }
    }
    let mut paths = Vec::new();
    let mut stack = vec![root.to_path_buf()];
    while let Some(dir) = stack.pop() {
        let Ok(entries) = std::fs::read_dir(&dir) else {
            continue;
        };
        for e in entries.flatten() {
            let p = e.path();
            let name = e.file_name();
            if p.is_dir() {
                if name != "target" && name != ".git" {
                    stack.push(p);
                }
            } else if let Ok(rel) = p.strip_prefix(root) {
                paths.push(rel.to_string_lossy().replace('\\', "/"));
            }
        }
    }
    paths
}

/// The tracked text files (UTF-8; binaries and deleted files skipped).
fn tracked_text_files() -> BTreeMap<String, String> {
    let root = root();
    tracked_paths(&root)
        .into_iter()
        .filter_map(|p| {
            let bytes = std::fs::read(root.join(&p)).ok()?;
            String::from_utf8(bytes).ok().map(|t| (p, t))
        })
        .collect()
}

#[test]
fn every_cited_doc_anchor_exists() {
    let files = tracked_text_files();
    assert!(
        files.contains_key("docs/science.md"),
        "docs/science.md is not tracked (found {} files)",
        files.len()
    );
    let cited = files
        .iter()
        .filter(|(p, _)| p.as_str() != SELF_PATH)
        .flat_map(|(_, t)| references(t, false))
        .filter(|r| r.path == "docs/science.md")
        .count();
    assert!(
        cited > 20,
        "only {cited} docs/science.md#... citations found"
    );
    let errors = broken_references(&files);
    assert!(
        errors.is_empty(),
        "{} broken reference(s):\n{}",
        errors.len(),
        errors.join("\n")
    );
}

#[test]
fn nothing_cites_the_out_of_repository_spec() {
    let hits = spec_citations(&tracked_text_files());
    assert!(hits.is_empty(), "{}", hits.join("\n"));
}

#[test]
fn slug_is_githubs() {
    assert_eq!(slug("Body model"), "body-model");
    assert_eq!(
        slug("  Joint and torque limits "),
        "joint-and-torque-limits"
    );
    assert_eq!(
        slug("The body model: `irlgrid simulate`"),
        "the-body-model-irlgrid-simulate"
    );
    assert_eq!(
        slug("Training a policy: `irlgrid train`, `evaluate`, `sample`"),
        "training-a-policy-irlgrid-train-evaluate-sample"
    );
    assert_eq!(slug("What's new (v2.0)?"), "whats-new-v20");
    assert_eq!(
        slug("snake_case and kebab-case"),
        "snake_case-and-kebab-case"
    );
    assert_eq!(slug("A  B"), "a--b");
    assert_eq!(slug("Größe"), "größe");
}

#[test]
fn headings_skip_code_and_repeat_with_a_suffix() {
    let doc = "# Title\n\n```sh\n# not a heading\n```\n## Part ##\n### Part\n    # indented code\n#hashtag\n";
    assert_eq!(headings(doc), ["Title", "Part", "Part"]);
    let got: Vec<String> = anchors(doc).into_iter().collect();
    assert_eq!(got, ["part", "part-1", "title"]);
}

#[test]
fn references_are_found_and_urls_skipped() {
    let text = "// docs/science.md#reward, see (docs/science.md#the-pull).\n\
                see https://example.org/README.md#x and /abs/a.md#y and docs/x.md#<section>\n\
                [a](../README.md#quick-start) [b](#local)\n";
    let got: Vec<String> = references(text, true)
        .iter()
        .map(|r| format!("{}:{}#{}", r.line, r.path, r.anchor))
        .collect();
    assert_eq!(
        got,
        [
            "1:docs/science.md#reward",
            "1:docs/science.md#the-pull",
            "3:../README.md#quick-start",
            "3:#local",
        ]
    );
    // Outside markdown an in-page link means nothing.
    assert_eq!(references("[b](#local)", false), []);
}

#[test]
fn relative_links_resolve_like_github() {
    assert_eq!(
        resolve("docs/deploy.md", "science.md").as_deref(),
        Some("docs/science.md")
    );
    assert_eq!(
        resolve("docs/deploy.md", "../README.md").as_deref(),
        Some("README.md")
    );
    assert_eq!(
        resolve("docs/deploy.md", "docs/science.md").as_deref(),
        Some("docs/science.md")
    );
    assert_eq!(
        resolve("src/main.rs", "docs/science.md").as_deref(),
        Some("docs/science.md")
    );
    assert_eq!(resolve("README.md", "../outside.md"), None);
    assert_eq!(resolve("README.md", "").as_deref(), Some("README.md"));
}

/// The check can fail: a made-up anchor, a missing document, a bad in-page
/// link and a spec citation are all reported; good references are not.
#[test]
fn checker_reports_what_is_missing() {
    let files: BTreeMap<String, String> = [
        (
            "docs/a.md",
            "# A\n\n## Real heading\n\n[up](#a) [gone](#nowhere)\n",
        ),
        (
            "src/x.rs",
            "// docs/a.md#real-heading\n// docs/a.md#made-up-anchor\n// docs/nofile.md#intro\n",
        ),
        ("docs/b.md", "[ok](a.md#real-heading) [bad](a.md#real)\n"),
    ]
    .into_iter()
    .map(|(p, t)| (p.to_string(), t.to_string()))
    .chain([(
        "tools/y.sh".to_string(),
        format!(
            "# see {}/{}.md\n# SPEC {}4\n",
            ["..", "shared"].join("/"),
            "SPEC",
            '\u{a7}'
        ),
    )])
    .collect();
    let errors = broken_references(&files);
    let has = |needle: &str| errors.iter().any(|e| e.contains(needle));
    assert_eq!(errors.len(), 4, "{errors:#?}");
    assert!(has("src/x.rs:2: docs/a.md#made-up-anchor"), "{errors:#?}");
    assert!(
        has("src/x.rs:3: docs/nofile.md#intro: no tracked file"),
        "{errors:#?}"
    );
    assert!(has("docs/a.md:5: #nowhere"), "{errors:#?}");
    assert!(has("docs/b.md:1: a.md#real:"), "{errors:#?}");
    assert_eq!(spec_citations(&files).len(), 2);
}

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
//!
//! The same tests are the link check of the book (`docs/`, built by
//! `mdbook build docs`) and of the README: every relative markdown link
//! names a tracked file, book pages link only inside `docs/`, every page is
//! a chapter of `docs/SUMMARY.md`, and neither cites issue numbers nor
//! anything beside the repository.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};
use std::process::Command;

/// This file, which necessarily contains the strings it forbids and
/// made-up references for its own negative tests.
const SELF_PATH: &str = "tests/doc_anchors.rs";

/// GitHub's heading slug, the one the generated API reference uses.
use coordinator::api_reference::slug;

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

/// One relative link of a markdown file: `[text](target)` or
/// `![alt](target)`, outside fenced code and inline code spans.
#[derive(Debug, PartialEq)]
struct Link {
    /// 1-based line of the link.
    line: usize,
    /// The target's path, without `#anchor` (may be empty for `(#x)`).
    path: String,
    /// The anchor after `#`, if any.
    anchor: Option<String>,
}

/// `line` with its inline code spans (between backticks) blanked out.
fn without_code_spans(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut in_code = false;
    for c in line.chars() {
        if c == '`' {
            in_code = !in_code;
            out.push(' ');
        } else {
            out.push(if in_code { ' ' } else { c });
        }
    }
    out
}

/// Every inline link and image of a markdown text whose target is not a
/// URL (no `scheme:`) and not absolute.
fn markdown_links(markdown: &str) -> Vec<Link> {
    let mut out = Vec::new();
    let mut fence: Option<&str> = None;
    for (i, raw) in markdown.lines().enumerate() {
        let trimmed = raw.trim_start();
        let marker = ["```", "~~~"].into_iter().find(|m| trimmed.starts_with(m));
        if let Some(m) = marker {
            fence = match fence {
                None => Some(m),
                Some(open) if open == m => None,
                other => other,
            };
            continue;
        }
        if fence.is_some() {
            continue;
        }
        let line = without_code_spans(raw);
        let mut rest = line.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let end = after.find(')').unwrap_or(after.len());
            let mut target = after[..end].trim();
            // `[x](<target>)` and `[x](target "title")`.
            target = target.trim_start_matches('<');
            target = target.split(['>', ' ']).next().unwrap_or("");
            rest = &after[end.min(after.len())..];
            let scheme = target
                .split_once(':')
                .is_some_and(|(s, _)| !s.is_empty() && s.chars().all(|c| c.is_ascii_alphabetic()));
            if target.is_empty() || scheme || target.starts_with('/') {
                continue;
            }
            let (path, anchor) = match target.split_once('#') {
                Some((p, a)) => (p.to_string(), Some(a.to_string())),
                None => (target.to_string(), None),
            };
            out.push(Link {
                line: i + 1,
                path,
                anchor,
            });
        }
    }
    out
}

/// The pages `docs/SUMMARY.md` lists (repository paths).
fn summary_pages(summary: &str) -> BTreeSet<String> {
    markdown_links(summary)
        .into_iter()
        .filter(|l| l.path.ends_with(".md"))
        .filter_map(|l| join("docs", &l.path))
        .collect()
}

/// Broken links of the book and the README, one message each: every
/// relative link of a tracked markdown file names a tracked file (links
/// resolve against the file's directory, as on GitHub and in the book),
/// with an anchor its heading offers; a link of a book page (under
/// `docs/`) stays inside `docs/` and names a file, not a folder, since the
/// built book has only what `docs/` holds; every page of `docs/` is a
/// chapter of `docs/SUMMARY.md`; and the README and the book cite no issue
/// numbers and nothing beside the repository (`../shared/`).
fn broken_links(files: &BTreeMap<String, String>) -> Vec<String> {
    let mut errors = Vec::new();
    let is_dir = |p: &str| {
        let prefix = format!("{}/", p.trim_end_matches('/'));
        files.keys().any(|f| f.starts_with(&prefix))
    };
    let in_book = |p: &str| p.starts_with("docs/");
    for (path, text) in files {
        if !path.ends_with(".md") || path == SELF_PATH {
            continue;
        }
        let book_page = in_book(path);
        let dir = Path::new(path)
            .parent()
            .and_then(Path::to_str)
            .unwrap_or("");
        for link in markdown_links(text) {
            let at = format!("{path}:{}", link.line);
            let shown = match &link.anchor {
                Some(a) => format!("{}#{a}", link.path),
                None => link.path.clone(),
            };
            if link.path.is_empty() {
                continue; // an in-page anchor: checked by broken_references
            }
            let Some(target) = join(dir, &link.path) else {
                errors.push(format!("{at}: {shown} points outside the repository"));
                continue;
            };
            if book_page && !in_book(&target) {
                errors.push(format!(
                    "{at}: {shown} leaves docs/ ({target}): the built book does not have it"
                ));
                continue;
            }
            let target = target.trim_end_matches('/').to_string();
            if let Some(doc) = files.get(&target) {
                if let (Some(anchor), true) = (&link.anchor, target.ends_with(".md")) {
                    if !anchor.is_empty() && !anchors(doc).contains(anchor) {
                        errors.push(format!(
                            "{at}: {shown}: {target} has no heading with slug {anchor:?}"
                        ));
                    }
                }
            } else if is_dir(&target) {
                if book_page {
                    errors.push(format!(
                        "{at}: {shown} is a folder: the built book has no folder pages"
                    ));
                }
            } else {
                errors.push(format!("{at}: {shown}: no tracked file {target}"));
            }
        }
    }
    if let Some(summary) = files.get("docs/SUMMARY.md") {
        let chapters = summary_pages(summary);
        for page in files.keys() {
            if in_book(page)
                && page.ends_with(".md")
                && page != "docs/SUMMARY.md"
                && !chapters.contains(page)
            {
                errors.push(format!("{page}: not a chapter of docs/SUMMARY.md"));
            }
        }
    }
    let outside = format!("../{}/", "shared");
    for (path, text) in files {
        if !(path == "README.md" || (in_book(path) && path.ends_with(".md"))) {
            continue;
        }
        for (i, line) in text.lines().enumerate() {
            let lower = line.to_lowercase();
            let cites_issue = lower
                .match_indices("issue ")
                .any(|(k, m)| lower[k + m.len()..].starts_with(|c: char| c.is_ascii_digit()));
            if cites_issue {
                errors.push(format!("{path}:{}: cites an issue number", i + 1));
            }
            if line.contains(&outside) {
                errors.push(format!("{path}:{}: refers to {outside}", i + 1));
            }
        }
    }
    errors
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

/// The tracked files with their text (deleted files skipped; a binary
/// file, such as an image a page shows, is there with an empty text, so
/// that links can name it).
fn tracked_text_files() -> BTreeMap<String, String> {
    let root = root();
    tracked_paths(&root)
        .into_iter()
        .filter_map(|p| {
            let bytes = std::fs::read(root.join(&p)).ok()?;
            Some((p, String::from_utf8(bytes).unwrap_or_default()))
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
fn every_link_of_the_readme_and_the_book_resolves() {
    let files = tracked_text_files();
    assert!(
        files.contains_key("docs/SUMMARY.md"),
        "docs/SUMMARY.md (the book's table of contents) is not tracked"
    );
    let links: usize = files
        .iter()
        .filter(|(p, _)| p.starts_with("docs/") && p.ends_with(".md"))
        .map(|(_, t)| markdown_links(t).len())
        .sum();
    assert!(links > 100, "only {links} links found in the book");
    let errors = broken_links(&files);
    assert!(
        errors.is_empty(),
        "{} broken link(s):\n{}",
        errors.len(),
        errors.join("\n")
    );
}

/// The link check can fail: each kind of broken link is reported, and
/// good links are not.
#[test]
fn link_checker_reports_what_is_broken() {
    let files: BTreeMap<String, String> = [
        (
            "README.md",
            "[ok](docs/a.md) [img](docs/img/x.png) [gone](docs/nope.md) [up](../outside.md)\n",
        ),
        (
            "docs/SUMMARY.md",
            "# Summary\n\n- [A](a.md)\n- [B](sub/b.md)\n",
        ),
        (
            "docs/a.md",
            "# A\n\n## Part\n\n[b](sub/b.md#b-heading) [bad anchor](sub/b.md#nope) \
             [readme](../README.md) [data](data/t.tsv) [folder](data/)\n\
             `[code](not/checked.md)`\n\n```\n[fenced](not/checked.md)\n```\n\
             [web](https://example.org/x.md) Fixed in issue 12.\n",
        ),
        (
            "docs/sub/b.md",
            "# B heading\n\n[back](../a.md#part) [spec](../../shared/x.md)\n",
        ),
        ("docs/orphan.md", "# Orphan\n"),
        ("docs/data/t.tsv", "a\tb\n"),
        ("docs/img/x.png", ""),
    ]
    .into_iter()
    .map(|(p, t)| (p.to_string(), t.to_string()))
    .collect();
    let errors = broken_links(&files);
    let has = |needle: &str| errors.iter().any(|e| e.contains(needle));
    assert!(
        has("README.md:1: docs/nope.md: no tracked file"),
        "{errors:#?}"
    );
    assert!(
        has("README.md:1: ../outside.md points outside"),
        "{errors:#?}"
    );
    assert!(
        has("docs/a.md:5: sub/b.md#nope: docs/sub/b.md has no heading"),
        "{errors:#?}"
    );
    assert!(has("docs/a.md:5: ../README.md leaves docs/"), "{errors:#?}");
    assert!(has("docs/a.md:5: data/ is a folder"), "{errors:#?}");
    assert!(has("docs/a.md:11: cites an issue number"), "{errors:#?}");
    assert!(
        has("docs/sub/b.md:3: ../../shared/x.md leaves docs/"),
        "{errors:#?}"
    );
    assert!(has("docs/sub/b.md:3: refers to ../shared/"), "{errors:#?}");
    assert!(has("docs/orphan.md: not a chapter"), "{errors:#?}");
    assert_eq!(errors.len(), 9, "{errors:#?}");
}

#[test]
fn markdown_links_skip_code_urls_and_titles() {
    let doc = "[a](x.md#y \"title\") ![i](<img/p.png>) `[c](code.md)` [u](mailto:x@y)\n    - [nested](n.md)\n";
    let got: Vec<String> = markdown_links(doc)
        .iter()
        .map(|l| format!("{}:{}#{:?}", l.line, l.path, l.anchor))
        .collect();
    assert_eq!(
        got,
        ["1:x.md#Some(\"y\")", "1:img/p.png#None", "2:n.md#None"]
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

//! The documents hold together: README.md stays a user's page that opens with the two commands,
//! every design reference in the code resolves to a heading of docs/design.md, and every relative
//! link in README.md and docs/*.md points to a file that exists. Only std: directories are walked
//! with `std::fs`.

use std::fs;
use std::path::{Path, PathBuf};

const README_MAX_LINES: usize = 250;

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(path: &Path) -> String {
    fs::read_to_string(path).unwrap_or_else(|e| panic!("{}: {e}", path.display()))
}

/// Files under `dir` (recursively) whose name ends with one of `exts`, sorted.
fn files(dir: &Path, exts: &[&str]) -> Vec<PathBuf> {
    let mut out = Vec::new();
    let mut stack = vec![dir.to_path_buf()];
    while let Some(d) = stack.pop() {
        let Ok(entries) = fs::read_dir(&d) else {
            continue;
        };
        for entry in entries.flatten() {
            let path = entry.path();
            if path.is_dir() {
                stack.push(path);
            } else if path
                .extension()
                .and_then(|e| e.to_str())
                .is_some_and(|e| exts.contains(&e))
            {
                out.push(path);
            }
        }
    }
    out.sort();
    out
}

/// The text after the hashes of every Markdown heading (outside fenced code).
fn headings(markdown: &str) -> Vec<String> {
    let mut fenced = false;
    let mut out = Vec::new();
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
        } else if !fenced && line.starts_with('#') {
            out.push(line.trim_start_matches('#').trim().to_string());
        }
    }
    out
}

/// Whether a heading's text starts with the section `x`: `2` matches `2. The method` but not
/// `2b. …` or `2.1 …`; `2.6` matches `2.6 The gap …`; `2b` matches `2b. What …`.
fn heading_is(heading: &str, x: &str) -> bool {
    let Some(rest) = heading.strip_prefix(x) else {
        return false;
    };
    let mut chars = rest.chars();
    match chars.next() {
        None | Some(' ') | Some(':') => true,
        Some('.') => !chars.next().is_some_and(|c| c.is_ascii_alphanumeric()),
        Some(_) => false,
    }
}

/// A section token after `§`: digits, optional lowercase letters, then `.digits` groups.
fn section_token(s: &str) -> Option<(String, &str)> {
    let bytes = s.as_bytes();
    let mut i = 0;
    while i < bytes.len() && bytes[i].is_ascii_digit() {
        i += 1;
    }
    if i == 0 {
        return None;
    }
    while i < bytes.len() && bytes[i].is_ascii_lowercase() {
        i += 1;
    }
    while i + 1 < bytes.len() && bytes[i] == b'.' && bytes[i + 1].is_ascii_digit() {
        i += 1;
        while i < bytes.len() && bytes[i].is_ascii_digit() {
            i += 1;
        }
    }
    Some((s[..i].to_string(), &s[i..]))
}

/// The sections cited by design references in `text`: `DESIGN §2.6`, `DESIGN.md §2b, §6`,
/// `DESIGN §3–§5`, `DESIGN.md §4–5`, `docs/design.md §2.6`, `design.md) §1`. A bare mention
/// (`DESIGN`, `docs/design.md`) cites the document only and yields nothing.
fn design_references(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    for marker in ["DESIGN", "design.md"] {
        let mut from = 0;
        while let Some(at) = text[from..].find(marker) {
            let start = from + at + marker.len();
            from = start;
            let mut rest = &text[start..];
            if marker == "DESIGN" {
                rest = rest.strip_prefix(".md").unwrap_or(rest);
            }
            // A Markdown link's closing parts may stand between the name and the section.
            rest = rest.trim_start_matches([')', ']', '`', ' ']);
            let Some(mut list) = rest.strip_prefix('§') else {
                continue;
            };
            while let Some((x, after)) = section_token(list) {
                out.push(x);
                // Continue on `, §Y`, `–§Y`, `–Y` and `-Y`.
                let next = if let Some(r) = after.strip_prefix(", §") {
                    r
                } else if let Some(r) = after.strip_prefix("–").or(after.strip_prefix('-')) {
                    r.strip_prefix('§').unwrap_or(r)
                } else {
                    break;
                };
                list = next;
            }
        }
    }
    out
}

/// Every design reference in `files` that no heading of `design` resolves, as `file: §X`.
fn unresolved(design: &str, files: &[PathBuf]) -> (usize, Vec<String>) {
    let heads = headings(design);
    let mut count = 0;
    let mut bad = Vec::new();
    for file in files {
        for x in design_references(&read(file)) {
            count += 1;
            if !heads.iter().any(|h| heading_is(h, &x)) {
                bad.push(format!("{}: §{x}", file.display()));
            }
        }
    }
    (count, bad)
}

#[test]
fn readme_is_short_and_opens_with_the_two_commands() {
    let readme = read(&root().join("README.md"));
    let lines = readme.lines().count();
    assert!(
        lines <= README_MAX_LINES,
        "README.md has {lines} lines, more than {README_MAX_LINES}"
    );
    // The first code block, within the first lines, holds the main job then the tests.
    let first: Vec<&str> = readme.lines().take(12).collect();
    let open = first
        .iter()
        .position(|l| l.starts_with("```"))
        .expect("README.md opens with a code block of the two commands");
    let commands: Vec<&str> = readme.lines().skip(open + 1).take(2).collect();
    assert!(
        commands.len() == 2
            && commands[0].starts_with("cargo run --release ")
            && commands[1].starts_with("cargo test --release "),
        "README.md's first code block must start with `cargo run --release` and `cargo test --release`: {commands:?}"
    );
    for word in ["the network before", "commit "] {
        assert!(
            !readme.contains(word),
            "README.md is a user's page: it mentions `{word}`"
        );
    }
}

#[test]
fn design_references_resolve_to_headings() {
    let root = root();
    let design = read(&root.join("docs/design.md"));
    let mut sources = files(&root.join("src"), &["rs"]);
    sources.extend(files(&root.join("shaders"), &["wgsl"]));
    sources.extend(files(&root.join("benches"), &["rs"]));
    sources.extend(files(&root.join("examples"), &["rs"]));
    sources.extend(
        files(&root.join("tests"), &["rs"])
            .into_iter()
            .filter(|p| !p.ends_with("tests/docs.rs")),
    );
    sources.push(root.join("README.md"));
    sources.extend(files(&root.join("docs"), &["md"]));
    let (count, bad) = unresolved(&design, &sources);
    assert!(
        count >= 10,
        "only {count} design references found: is the scan broken?"
    );
    assert!(
        bad.is_empty(),
        "design references without a heading in docs/design.md:\n{}",
        bad.join("\n")
    );
}

#[test]
fn the_reference_check_fails_on_a_broken_reference() {
    let design = "## 1. The problem\n## 2. The method\n### 2.6 The gap\n## 2b. Tubes\n";
    assert_eq!(
        design_references("(DESIGN §2.6: x) DESIGN.md §2b, §1; DESIGN §1–§2, docs/design.md §4–5"),
        ["2.6", "2b", "1", "1", "2", "4", "5"]
    );
    assert!(design_references("DESIGN and docs/design.md, paper §3").is_empty());
    let heads = headings(design);
    for x in ["1", "2", "2.6", "2b"] {
        assert!(heads.iter().any(|h| heading_is(h, x)), "§{x}");
    }
    for x in ["3", "2.1", "2c", "6"] {
        assert!(
            !heads.iter().any(|h| heading_is(h, x)),
            "§{x} must not resolve"
        );
    }
    // `§2` must not be satisfied by `2b.` or `2.6` alone.
    let only_sub = headings("## 2b. Tubes\n### 2.6 The gap\n");
    assert!(!only_sub.iter().any(|h| heading_is(h, "2")));
    // And through a file, as the real check reads them.
    let dir = std::env::temp_dir().join(format!("cbfreach-docs-{}", std::process::id()));
    fs::create_dir_all(&dir).unwrap();
    let file = dir.join("broken.rs");
    fs::write(&file, "//! See DESIGN §2.6 and DESIGN §7.\n").unwrap();
    let (count, bad) = unresolved(design, &[file]);
    fs::remove_dir_all(&dir).ok();
    assert_eq!(count, 2);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].ends_with("§7"));
}

/// Relative link targets `[text](target)` outside fenced code, without their `#anchor`.
fn relative_links(markdown: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut fenced = false;
    for line in markdown.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        // Inline code (`[J](x − p)`) holds no links: keep what lies outside backticks.
        let prose: String = line.split('`').step_by(2).collect::<Vec<_>>().join(" ");
        let mut rest = prose.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            let target = after[..end].trim();
            let target = target.split_whitespace().next().unwrap_or("");
            rest = &after[end..];
            let external = ["http://", "https://", "mailto:", "#"]
                .iter()
                .any(|p| target.starts_with(p));
            if external || target.is_empty() {
                continue;
            }
            let path = target.split('#').next().unwrap_or("");
            out.push(path.to_string());
        }
    }
    out
}

#[test]
fn relative_links_point_to_files() {
    let root = root();
    let mut documents = vec![root.join("README.md")];
    documents.extend(files(&root.join("docs"), &["md"]));
    assert!(
        documents.len() >= 4,
        "README.md and docs/*.md: {documents:?}"
    );
    let mut bad = Vec::new();
    let mut count = 0;
    for doc in &documents {
        let dir = doc.parent().unwrap();
        for link in relative_links(&read(doc)) {
            count += 1;
            if !dir.join(&link).exists() {
                bad.push(format!("{}: {link}", doc.display()));
            }
        }
    }
    assert!(count > 0, "no relative links found");
    assert!(
        bad.is_empty(),
        "links to files that do not exist:\n{}",
        bad.join("\n")
    );
    assert_eq!(
        relative_links("[a](x.md#s) [b](https://e.org) [c](#top) `[J](x)`\n```\n[d](no)\n```"),
        ["x.md"]
    );
}

//! The documentation's relative links, checked by `cargo xtask layout`: every relative link in
//! `README.md`, `ARCHITECTURE.md` and `docs/**/*.md` must point to a file or directory that exists
//! and, when it names an anchor (`file.md#anchor`, or `#anchor` in the same file), to a heading
//! of that Markdown file.
//!
//! Anchors follow GitHub's rule for headings: the heading's text lowercased, every character
//! that is not a letter, a digit, a combining mark, `-`, `_` or a space dropped (backticks,
//! colons, parentheses, commas, apostrophes, …), each space turned into `-`; a heading whose
//! anchor already exists in the file gets `-1`, `-2`, … Links inside fenced code blocks and
//! inline code spans are not links. Absolute URLs (`http:`, `https:`, `mailto:`) are not
//! checked.

use std::collections::BTreeSet;
use std::fs;
use std::path::{Path, PathBuf};

/// One broken link: where it is and why.
#[derive(Debug, PartialEq, Eq)]
pub(crate) struct Broken {
    pub(crate) file: PathBuf,
    pub(crate) line: usize,
    pub(crate) target: String,
    pub(crate) why: &'static str,
}

/// The Markdown files whose links are checked, relative to the repository root: the README,
/// the architecture document and every `.md` file under `docs/` (its subdirectories included).
pub(crate) fn documents(root: &Path) -> Result<Vec<PathBuf>, String> {
    let mut files = vec![root.join("README.md"), root.join("ARCHITECTURE.md")];
    let mut more = Vec::new();
    let docs = root.join("docs");
    if docs.is_dir() {
        crate::layout::files_with_extension(&docs, "md", &mut more)?;
    }
    more.sort();
    files.extend(more);
    Ok(files.into_iter().filter(|f| f.is_file()).collect())
}

/// Every broken relative link of `files`.
pub(crate) fn check(files: &[PathBuf]) -> Result<Vec<Broken>, String> {
    let mut broken = Vec::new();
    for file in files {
        let text = fs::read_to_string(file).map_err(|e| format!("{}: {e}", file.display()))?;
        let dir = file.parent().unwrap_or(Path::new("."));
        for (line, target) in links(&text) {
            let (path, anchor) = match target.split_once('#') {
                Some((p, a)) => (p, Some(a)),
                None => (target.as_str(), None),
            };
            let dest = if path.is_empty() {
                file.clone()
            } else {
                dir.join(path)
            };
            let mut report = |why| {
                broken.push(Broken {
                    file: file.clone(),
                    line,
                    target: target.clone(),
                    why,
                })
            };
            if !dest.exists() {
                report("no such file");
                continue;
            }
            let Some(anchor) = anchor else { continue };
            if dest.extension().is_none_or(|e| e != "md") {
                continue;
            }
            let dest_text =
                fs::read_to_string(&dest).map_err(|e| format!("{}: {e}", dest.display()))?;
            if !anchors(&dest_text).contains(anchor) {
                report("no such heading");
            }
        }
    }
    Ok(broken)
}

/// The relative link targets of a Markdown text with their 1-based line numbers.
fn links(text: &str) -> Vec<(usize, String)> {
    let mut out = Vec::new();
    let mut fenced = false;
    for (i, line) in text.lines().enumerate() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let line = strip_code_spans(line);
        let mut rest = line.as_str();
        while let Some(at) = rest.find("](") {
            let after = &rest[at + 2..];
            let Some(end) = after.find(')') else { break };
            let target = after[..end].trim();
            let target = target.split_whitespace().next().unwrap_or("");
            let external = ["http:", "https:", "mailto:"]
                .iter()
                .any(|p| target.starts_with(p));
            if !target.is_empty() && !external {
                out.push((i + 1, target.to_string()));
            }
            rest = &after[end..];
        }
    }
    out
}

/// The line with the contents of its inline code spans blanked.
fn strip_code_spans(line: &str) -> String {
    let mut out = String::with_capacity(line.len());
    let mut in_code = false;
    for c in line.chars() {
        if c == '`' {
            in_code = !in_code;
            out.push(c);
        } else if in_code {
            out.push(' ');
        } else {
            out.push(c);
        }
    }
    out
}

/// The heading anchors of a Markdown text (GitHub's rule, duplicates numbered).
pub(crate) fn anchors(text: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let mut fenced = false;
    for line in text.lines() {
        if line.trim_start().starts_with("```") {
            fenced = !fenced;
            continue;
        }
        if fenced {
            continue;
        }
        let hashes = line.chars().take_while(|&c| c == '#').count();
        if !(1..=6).contains(&hashes) || !line[hashes..].starts_with(' ') {
            continue;
        }
        let base = slug(line[hashes..].trim());
        let mut anchor = base.clone();
        let mut n = 0;
        while out.contains(&anchor) {
            n += 1;
            anchor = format!("{base}-{n}");
        }
        out.insert(anchor);
    }
    out
}

/// GitHub's anchor of a heading's text.
pub(crate) fn slug(heading: &str) -> String {
    heading
        .to_lowercase()
        .chars()
        .filter(|&c| c.is_alphanumeric() || is_combining_mark(c) || matches!(c, '-' | '_' | ' '))
        .map(|c| if c == ' ' { '-' } else { c })
        .collect()
}

/// Combining diacritical marks (kept in anchors, as letters are).
fn is_combining_mark(c: char) -> bool {
    matches!(c, '\u{0300}'..='\u{036F}' | '\u{1AB0}'..='\u{1AFF}' | '\u{20D0}'..='\u{20FF}')
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn slugs_follow_githubs_rule() {
        assert_eq!(
            slug("Transfer alignment: flight configuration (`FlightFilter`, `TaConfig::flight`)"),
            "transfer-alignment-flight-configuration-flightfilter-taconfigflight"
        );
        assert_eq!(
            slug("What `cargo xtask sim` produces"),
            "what-cargo-xtask-sim-produces"
        );
        assert_eq!(
            slug("The straight carry's level σ, measured"),
            "the-straight-carrys-level-σ-measured"
        );
        assert_eq!(slug("nav-core's shared layer"), "nav-cores-shared-layer");
    }

    #[test]
    fn duplicate_headings_are_numbered_and_code_is_not_a_heading() {
        let a = anchors("# A\n## A\n```\n# not a heading\n```\n#also not\n");
        assert_eq!(a, ["a", "a-1"].iter().map(|s| s.to_string()).collect());
    }

    #[test]
    fn links_skip_code_and_urls() {
        let text = "[a](x.md#y) `[b](z.md)` [c](https://e.org)\n```\n[d](w.md)\n```\n[e](#f)\n";
        assert_eq!(
            links(text),
            vec![(1, "x.md#y".to_string()), (5, "#f".to_string())]
        );
    }

    #[test]
    fn a_missing_file_or_heading_is_reported() {
        let dir = std::env::temp_dir().join(format!("xtask-links-{}", std::process::id()));
        fs::create_dir_all(dir.join("docs")).unwrap();
        let readme = dir.join("README.md");
        fs::write(
            &readme,
            "# Top\n[ok](docs/a.md#here) [no file](docs/b.md) [no heading](docs/a.md#there) \
             [self](#top) [self broken](#bottom)\n",
        )
        .unwrap();
        fs::write(
            dir.join("docs/a.md"),
            "# A\n## Here\n[back](../README.md#top)\n",
        )
        .unwrap();
        let files = documents(&dir).unwrap();
        let broken = check(&files).unwrap();
        let found: Vec<(&str, &str)> = broken.iter().map(|b| (b.target.as_str(), b.why)).collect();
        assert_eq!(
            found,
            vec![
                ("docs/b.md", "no such file"),
                ("docs/a.md#there", "no such heading"),
                ("#bottom", "no such heading"),
            ]
        );
        fs::remove_dir_all(&dir).unwrap();
    }
}

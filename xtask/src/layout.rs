//! `cargo xtask layout [--strict]`: the code-layout limits a newcomer relies on, checked on the
//! sources of `nav-core` and `nav-sim`:
//!
//! * no source file over [`MAX_FILE_LINES`] lines;
//! * no function over [`MAX_FN_LINES`] lines, counted from the line of its `fn` keyword to the
//!   line of its closing brace (a brace-matching scan with comments, strings and character
//!   literals blanked first; trait methods without a body are not functions here);
//! * no import cycle between sibling modules: module `a` depends on its sibling `b` when any
//!   file of `a` (or of a module inside it) names a path through `b` (`super::b::…`,
//!   `crate::…::b::…`, `use` trees included); a strongly connected group of siblings is a cycle;
//! * no broken relative link in `README.md`, `ARCHITECTURE.md` and `docs/**/*.md` (a missing file or
//!   heading anchor; [`crate::links`]).
//!
//! Files under a `generated/` directory are exempt from the length limits: they are written by
//! `cargo xtask gen` (straight-line kernels), not by hand. They still take part in the import
//! graph.
//!
//! Without `--strict` the command reports and succeeds; with it, it fails on any finding (what CI
//! runs once the tree is clean).

use std::collections::{BTreeMap, BTreeSet};
use std::fs;
use std::path::{Path, PathBuf};

/// Longest source file allowed, in lines.
pub(crate) const MAX_FILE_LINES: usize = 600;
/// Longest function allowed, in lines (from `fn` to its closing brace, both included).
pub(crate) const MAX_FN_LINES: usize = 80;

/// The crates checked, with their crate roots (each root is its own module tree).
const CRATES: [(&str, &[&str]); 2] = [
    ("nav-core", &["src/lib.rs"]),
    ("nav-sim", &["src/lib.rs", "src/main.rs"]),
];

/// Entry point of `cargo xtask layout`.
pub(crate) fn layout(strict: bool) -> Result<(), String> {
    let root = crate::root();
    let mut findings = 0usize;
    let mut long_files = Vec::new();
    let mut long_fns = Vec::new();
    let mut cycles = Vec::new();
    for (krate, roots) in CRATES {
        let src = root.join(krate).join("src");
        let mut files = Vec::new();
        files_with_extension(&src, "rs", &mut files)?;
        files.sort();
        for file in &files {
            let rel = file.strip_prefix(&root).unwrap_or(file).to_path_buf();
            if is_generated(&rel) {
                continue;
            }
            let text = read(file)?;
            let lines = text.lines().count();
            if lines > MAX_FILE_LINES {
                long_files.push((rel.clone(), lines));
            }
            let cleaned = blank_comments_and_literals(text.as_bytes());
            for f in functions(&cleaned) {
                if f.lines > MAX_FN_LINES {
                    long_fns.push((rel.clone(), f));
                }
            }
        }
        for crate_root in roots {
            let tree = ModuleTree::load(&root, &root.join(krate).join(crate_root))?;
            for cycle in tree.sibling_cycles() {
                cycles.push(format!("{krate}: {cycle}"));
            }
        }
    }
    long_files.sort_by_key(|f| std::cmp::Reverse(f.1));
    long_fns.sort_by_key(|f| std::cmp::Reverse(f.1.lines));

    println!(
        "layout: files over {MAX_FILE_LINES} lines ({}; `generated/` exempt):",
        long_files.len()
    );
    for (path, lines) in &long_files {
        println!("  {lines:5}  {}", path.display());
    }
    println!(
        "layout: functions over {MAX_FN_LINES} lines ({}):",
        long_fns.len()
    );
    for (path, f) in &long_fns {
        println!("  {:5}  {}:{}  {}", f.lines, path.display(), f.line, f.name);
    }
    println!(
        "layout: import cycles between sibling modules ({}):",
        cycles.len()
    );
    for c in &cycles {
        println!("  {c}");
    }
    let broken = crate::links::check(&crate::links::documents(&root)?)?;
    println!(
        "layout: broken relative links in README.md, ARCHITECTURE.md, docs/**/*.md ({}):",
        broken.len()
    );
    for b in &broken {
        let file = b.file.strip_prefix(&root).unwrap_or(&b.file);
        println!("  {}:{}  {}  ({})", file.display(), b.line, b.target, b.why);
    }
    findings += long_files.len() + long_fns.len() + cycles.len() + broken.len();
    if strict && findings > 0 {
        Err(format!("layout: {findings} finding(s)"))
    } else {
        Ok(())
    }
}

fn read(path: &Path) -> Result<String, String> {
    fs::read_to_string(path).map_err(|e| format!("{}: {e}", path.display()))
}

fn is_generated(rel: &Path) -> bool {
    rel.components().any(|c| c.as_os_str() == "generated")
}

/// Every file under `dir` (recursively) whose extension is `ext`, into `out`.
pub(crate) fn files_with_extension(
    dir: &Path,
    ext: &str,
    out: &mut Vec<PathBuf>,
) -> Result<(), String> {
    let entries = fs::read_dir(dir).map_err(|e| format!("{}: {e}", dir.display()))?;
    for entry in entries {
        let path = entry.map_err(|e| format!("{}: {e}", dir.display()))?.path();
        if path.is_dir() {
            files_with_extension(&path, ext, out)?;
        } else if path.extension().is_some_and(|e| e == ext) {
            out.push(path);
        }
    }
    Ok(())
}

/// The source with comments and the contents of string, byte-string and character literals
/// replaced by spaces (newlines kept), so byte offsets and line numbers are the original ones
/// and every remaining brace is code.
pub(crate) fn blank_comments_and_literals(src: &[u8]) -> Vec<u8> {
    let mut out = src.to_vec();
    let blank = |out: &mut Vec<u8>, from: usize, to: usize| {
        for b in out.iter_mut().take(to).skip(from) {
            if *b != b'\n' {
                *b = b' ';
            }
        }
    };
    let ident = |b: u8| b.is_ascii_alphanumeric() || b == b'_';
    let at = |i: usize| src.get(i).copied().unwrap_or(0);
    let mut i = 0;
    while i < src.len() {
        let c = at(i);
        if c == b'/' && at(i + 1) == b'/' {
            let end = src[i..]
                .iter()
                .position(|&b| b == b'\n')
                .map_or(src.len(), |p| i + p);
            blank(&mut out, i, end);
            i = end;
        } else if c == b'/' && at(i + 1) == b'*' {
            let mut depth = 0usize;
            let mut j = i;
            while j < src.len() {
                if at(j) == b'/' && at(j + 1) == b'*' {
                    depth += 1;
                    j += 2;
                } else if at(j) == b'*' && at(j + 1) == b'/' {
                    depth -= 1;
                    j += 2;
                    if depth == 0 {
                        break;
                    }
                } else {
                    j += 1;
                }
            }
            blank(&mut out, i, j);
            i = j;
        } else if (c == b'r' || (c == b'b' && at(i + 1) == b'r'))
            && (i == 0 || !ident(at(i - 1)))
            && {
                let k = if c == b'b' { i + 2 } else { i + 1 };
                let hashes = src[k.min(src.len())..]
                    .iter()
                    .take_while(|&&b| b == b'#')
                    .count();
                at(k + hashes) == b'"'
            }
        {
            let k = if c == b'b' { i + 2 } else { i + 1 };
            let hashes = src[k..].iter().take_while(|&&b| b == b'#').count();
            let body = k + hashes + 1;
            let mut close = Vec::with_capacity(hashes + 1);
            close.push(b'"');
            close.extend(std::iter::repeat_n(b'#', hashes));
            let end = src[body..]
                .windows(close.len())
                .position(|w| w == close.as_slice())
                .map_or(src.len(), |p| body + p);
            blank(&mut out, body, end);
            i = (end + close.len()).min(src.len());
        } else if c == b'"' {
            let mut j = i + 1;
            while j < src.len() && at(j) != b'"' {
                j += if at(j) == b'\\' { 2 } else { 1 };
            }
            blank(&mut out, i + 1, j.min(src.len()));
            i = j + 1;
        } else if c == b'\'' {
            // A character literal ('x', '\n', '\u{…}', a multi-byte character) or a lifetime.
            if at(i + 1) == b'\\' {
                let mut j = i + 2;
                while j < src.len() && at(j) != b'\'' {
                    j += 1;
                }
                blank(&mut out, i + 1, j);
                i = j + 1;
            } else {
                let width = match at(i + 1) {
                    b if b < 0x80 => 1,
                    b if b >= 0xF0 => 4,
                    b if b >= 0xE0 => 3,
                    _ => 2,
                };
                if at(i + 1 + width) == b'\'' {
                    blank(&mut out, i + 1, i + 1 + width);
                    i += 2 + width;
                } else {
                    i += 1;
                }
            }
        } else if ident(c) {
            // Skip the whole identifier so `br` / `r` inside one is never read as a raw string.
            while i < src.len() && ident(at(i)) {
                i += 1;
            }
        } else {
            i += 1;
        }
    }
    out
}

/// A function with a body found in blanked source.
#[derive(Debug)]
pub(crate) struct FnSpan {
    pub(crate) name: String,
    /// Line of the `fn` keyword (1-based).
    pub(crate) line: usize,
    /// Lines from the `fn` keyword to the closing brace, both included.
    pub(crate) lines: usize,
}

fn is_ident(b: u8) -> bool {
    b.is_ascii_alphanumeric() || b == b'_'
}

/// Every `fn name … { … }` in blanked source (nested functions and closures' enclosing
/// functions included; `fn(…)` pointer types and bodiless declarations skipped).
pub(crate) fn functions(src: &[u8]) -> Vec<FnSpan> {
    let line_of = |pos: usize| 1 + src[..pos].iter().filter(|&&b| b == b'\n').count();
    let mut out = Vec::new();
    let mut i = 0;
    while let Some(p) = find_word(src, b"fn", i) {
        i = p + 2;
        let mut j = i;
        while j < src.len() && src[j].is_ascii_whitespace() {
            j += 1;
        }
        let name_start = j;
        while j < src.len() && is_ident(src[j]) {
            j += 1;
        }
        if j == name_start {
            continue; // `fn(` pointer type
        }
        let name = String::from_utf8_lossy(&src[name_start..j]).into_owned();
        // The signature ends at the first `{` or `;` outside parentheses and brackets.
        let mut depth = 0i32;
        let mut open = None;
        while j < src.len() {
            match src[j] {
                b'(' | b'[' => depth += 1,
                b')' | b']' => depth -= 1,
                b'{' if depth == 0 => {
                    open = Some(j);
                    break;
                }
                b';' if depth == 0 => break,
                _ => {}
            }
            j += 1;
        }
        let Some(open) = open else { continue };
        let Some(close) = matching_brace(src, open) else {
            continue;
        };
        let line = line_of(p);
        out.push(FnSpan {
            name,
            line,
            lines: line_of(close) - line + 1,
        });
    }
    out
}

fn matching_brace(src: &[u8], open: usize) -> Option<usize> {
    let mut depth = 0usize;
    for (k, &b) in src.iter().enumerate().skip(open) {
        match b {
            b'{' => depth += 1,
            b'}' => {
                depth -= 1;
                if depth == 0 {
                    return Some(k);
                }
            }
            _ => {}
        }
    }
    None
}

/// The next occurrence of `word` at or after `from` that is a whole identifier.
fn find_word(src: &[u8], word: &[u8], from: usize) -> Option<usize> {
    let mut i = from;
    while i + word.len() <= src.len() {
        let p = i + src[i..].windows(word.len()).position(|w| w == word)?;
        let before_ok = p == 0 || !is_ident(src[p - 1]);
        let after_ok = src.get(p + word.len()).is_none_or(|&b| !is_ident(b));
        if before_ok && after_ok {
            return Some(p);
        }
        i = p + 1;
    }
    None
}

/// The module tree of one crate root, with the absolute module paths each module names.
struct ModuleTree {
    /// Every module's absolute path (the crate root is the empty path).
    modules: BTreeSet<Vec<String>>,
    /// (module where the path is written, absolute path named).
    references: Vec<(Vec<String>, Vec<String>)>,
}

impl ModuleTree {
    fn load(repo: &Path, crate_root: &Path) -> Result<Self, String> {
        let mut tree = ModuleTree {
            modules: BTreeSet::new(),
            references: Vec::new(),
        };
        tree.modules.insert(Vec::new());
        tree.load_file(repo, crate_root, &[], true)?;
        Ok(tree)
    }

    /// Reads one file of module `module`; `mod_rs` when its children live in its own directory
    /// (`lib.rs`, `main.rs`, `mod.rs`) rather than in a directory named after it.
    fn load_file(
        &mut self,
        repo: &Path,
        file: &Path,
        module: &[String],
        mod_rs: bool,
    ) -> Result<(), String> {
        let raw = read(file)?;
        let src = blank_comments_and_literals(raw.as_bytes());
        let dir = file.parent().unwrap_or(repo).to_path_buf();
        let child_dir = if mod_rs {
            dir.clone()
        } else {
            let stem = file
                .file_stem()
                .map(|s| s.to_os_string())
                .unwrap_or_default();
            dir.join(stem)
        };
        // Inline `mod name { … }` blocks: (module path, byte offsets of its braces).
        let mut inline: Vec<(Vec<String>, usize, usize)> = Vec::new();
        let current = |inline: &Vec<(Vec<String>, usize, usize)>, pos: usize| -> Vec<String> {
            // The innermost block around `pos`: the one that opens last.
            inline
                .iter()
                .filter(|(_, open, close)| *open < pos && pos < *close)
                .max_by_key(|(_, open, _)| *open)
                .map_or_else(|| module.to_vec(), |(m, _, _)| m.clone())
        };
        let mut i = 0;
        while let Some(p) = find_word(&src, b"mod", i) {
            i = p + 3;
            let (name, after) = ident_at(&src, skip_ws(&src, i));
            if name.is_empty() {
                continue;
            }
            let k = skip_ws(&src, after);
            let here = current(&inline, p);
            let mut child = here.clone();
            child.push(name.clone());
            match src.get(k) {
                Some(b'{') => {
                    if let Some(close) = matching_brace(&src, k) {
                        inline.push((child.clone(), k, close));
                        self.modules.insert(child);
                    }
                }
                Some(b';') if here.len() == module.len() => {
                    let path = path_attribute(&raw, &src, p)
                        .map(|p| dir.join(p))
                        .or_else(|| {
                            let flat = child_dir.join(format!("{name}.rs"));
                            let nested = child_dir.join(&name).join("mod.rs");
                            [flat, nested].into_iter().find(|f| f.is_file())
                        });
                    if let Some(path) = path {
                        let is_mod_rs = path.file_name().is_some_and(|n| n == "mod.rs");
                        self.modules.insert(child.clone());
                        self.load_file(repo, &path, &child, is_mod_rs)?;
                    }
                }
                _ => {}
            }
        }
        for keyword in [&b"crate"[..], b"super", b"self"] {
            let mut i = 0;
            while let Some(p) = find_word(&src, keyword, i) {
                i = p + keyword.len();
                if src.get(i..i + 2) != Some(b"::") {
                    continue;
                }
                // `self::` right after `super::` / `crate::` is part of a longer path, read there.
                if p >= 2 && &src[p - 2..p] == b"::" {
                    continue;
                }
                let here = current(&inline, p);
                let mut paths = Vec::new();
                use_tree(&src, p, Vec::new(), &mut paths);
                for path in paths {
                    if let Some(abs) = resolve(&here, &path) {
                        self.references.push((here.clone(), abs));
                    }
                }
            }
        }
        Ok(())
    }

    /// Sibling modules that depend on each other, as `parent: a -> b -> a` lines.
    fn sibling_cycles(&self) -> Vec<String> {
        // parent → (from → {to})
        let mut edges: BTreeMap<Vec<String>, BTreeMap<String, BTreeSet<String>>> = BTreeMap::new();
        for (from, to) in &self.references {
            let common = from.iter().zip(to).take_while(|(a, b)| a == b).count();
            if common < from.len() && common < to.len() {
                let target: Vec<String> = to[..=common].to_vec();
                if self.modules.contains(&target) {
                    edges
                        .entry(from[..common].to_vec())
                        .or_default()
                        .entry(from[common].clone())
                        .or_default()
                        .insert(to[common].clone());
                }
            }
        }
        let mut out = Vec::new();
        for (parent, graph) in &edges {
            for component in strongly_connected(graph) {
                if component.len() > 1 {
                    let parent = if parent.is_empty() {
                        "crate".to_string()
                    } else {
                        parent.join("::")
                    };
                    let detail: Vec<String> = component
                        .iter()
                        .map(|m| {
                            let deps: Vec<&str> = graph
                                .get(m)
                                .into_iter()
                                .flatten()
                                .filter(|d| component.contains(*d))
                                .map(String::as_str)
                                .collect();
                            format!("{m} -> {{{}}}", deps.join(", "))
                        })
                        .collect();
                    out.push(format!("{parent}: {}", detail.join("; ")));
                }
            }
        }
        out
    }
}

fn skip_ws(src: &[u8], mut i: usize) -> usize {
    while i < src.len() && src[i].is_ascii_whitespace() {
        i += 1;
    }
    i
}

fn ident_at(src: &[u8], i: usize) -> (String, usize) {
    let mut j = i;
    while j < src.len() && is_ident(src[j]) {
        j += 1;
    }
    (String::from_utf8_lossy(&src[i..j]).into_owned(), j)
}

/// The `#[path = "…"]` attribute directly before the `mod` at `pos`, if any.
fn path_attribute(raw: &str, src: &[u8], pos: usize) -> Option<String> {
    // Back to the end of the previous item.
    let start = src[..pos]
        .iter()
        .rposition(|&b| b == b';' || b == b'}' || b == b'{')
        .map_or(0, |p| p + 1);
    let attrs = raw.get(start..pos)?;
    let at = attrs.find("#[path")?;
    let rest = &attrs[at..];
    let open = rest.find('"')? + 1;
    let len = rest[open..].find('"')?;
    Some(rest[open..open + len].to_string())
}

/// The paths of the use tree (or plain path) starting at `i`, each as its segments.
fn use_tree(src: &[u8], i: usize, prefix: Vec<String>, out: &mut Vec<Vec<String>>) -> usize {
    let mut path = prefix;
    let mut i = skip_ws(src, i);
    loop {
        if src.get(i) == Some(&b'{') {
            i += 1;
            loop {
                i = skip_ws(src, i);
                match src.get(i) {
                    Some(b'}') => return i + 1,
                    Some(b',') => i += 1,
                    None => return i,
                    _ => {
                        let next = use_tree(src, i, path.clone(), out);
                        if next == i {
                            return i; // not a use tree after all
                        }
                        i = next;
                    }
                }
            }
        }
        let (seg, after) = ident_at(src, i);
        if seg.is_empty() {
            if src.get(i) == Some(&b'*') {
                out.push(path);
                return i + 1;
            }
            out.push(path);
            return i;
        }
        path.push(seg);
        let k = skip_ws(src, after);
        if src.get(k..k + 2) == Some(b"::") {
            i = skip_ws(src, k + 2);
        } else {
            out.push(path);
            return after;
        }
    }
}

/// `path` (starting with `crate`, `super` or `self`) written in module `here`, made absolute.
fn resolve(here: &[String], path: &[String]) -> Option<Vec<String>> {
    let mut abs: Vec<String> = here.to_vec();
    let mut segs = path.iter().peekable();
    match segs.peek().map(|s| s.as_str()) {
        Some("crate") => {
            abs.clear();
            segs.next();
        }
        Some("self") => {
            segs.next();
        }
        _ => {}
    }
    while segs.peek().is_some_and(|s| *s == "super") {
        abs.pop()?;
        segs.next();
    }
    abs.extend(segs.cloned());
    Some(abs)
}

/// Tarjan's strongly connected components of a small graph.
fn strongly_connected(graph: &BTreeMap<String, BTreeSet<String>>) -> Vec<BTreeSet<String>> {
    struct State<'a> {
        graph: &'a BTreeMap<String, BTreeSet<String>>,
        index: BTreeMap<&'a str, usize>,
        low: BTreeMap<&'a str, usize>,
        stack: Vec<&'a str>,
        on_stack: BTreeSet<&'a str>,
        out: Vec<BTreeSet<String>>,
    }
    fn visit<'a>(s: &mut State<'a>, v: &'a str) {
        let n = s.index.len();
        s.index.insert(v, n);
        s.low.insert(v, n);
        s.stack.push(v);
        s.on_stack.insert(v);
        let graph = s.graph;
        for w in graph.get(v).into_iter().flatten() {
            let w = w.as_str();
            if !s.index.contains_key(w) {
                visit(s, w);
                let lw = s.low[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(lw));
            } else if s.on_stack.contains(w) {
                let iw = s.index[w];
                let lv = s.low[v];
                s.low.insert(v, lv.min(iw));
            }
        }
        if s.low[v] == s.index[v] {
            let mut component = BTreeSet::new();
            while let Some(w) = s.stack.pop() {
                s.on_stack.remove(w);
                component.insert(w.to_string());
                if w == v {
                    break;
                }
            }
            s.out.push(component);
        }
    }
    let mut s = State {
        graph,
        index: BTreeMap::new(),
        low: BTreeMap::new(),
        stack: Vec::new(),
        on_stack: BTreeSet::new(),
        out: Vec::new(),
    };
    for v in graph.keys() {
        if !s.index.contains_key(v.as_str()) {
            visit(&mut s, v);
        }
    }
    s.out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn braces_in_comments_strings_and_chars_are_not_code() {
        let src = "fn a() {\n    let s = \"}}\"; // }\n    let c = '}';\n    /* } */\n    let r = r#\"}\"#;\n}\nfn b<'x>(v: &'x u8) -> u8 {\n    *v\n}\n";
        let cleaned = blank_comments_and_literals(src.as_bytes());
        let fns = functions(&cleaned);
        let spans: Vec<(&str, usize, usize)> = fns
            .iter()
            .map(|f| (f.name.as_str(), f.line, f.lines))
            .collect();
        assert_eq!(spans, vec![("a", 1, 6), ("b", 7, 3)]);
    }

    #[test]
    fn bodiless_declarations_and_pointer_types_are_skipped() {
        let src = "trait T {\n    fn f(&self);\n}\nfn g(h: fn(u8) -> u8) -> u8 {\n    h(1)\n}\n";
        let cleaned = blank_comments_and_literals(src.as_bytes());
        let names: Vec<String> = functions(&cleaned).into_iter().map(|f| f.name).collect();
        assert_eq!(names, vec!["g".to_string()]);
    }

    #[test]
    fn use_trees_resolve_to_absolute_paths() {
        let src = b"use super::{a::X, b, c::{d, e::*}};";
        let mut paths = Vec::new();
        use_tree(src, 4, Vec::new(), &mut paths);
        let here = vec!["m".to_string(), "n".to_string()];
        let abs: Vec<String> = paths
            .iter()
            .filter_map(|p| resolve(&here, p))
            .map(|p| p.join("::"))
            .collect();
        assert_eq!(abs, vec!["m::a::X", "m::b", "m::c::d", "m::c::e"]);
    }

    #[test]
    fn a_two_module_cycle_is_found() {
        let graph: BTreeMap<String, BTreeSet<String>> =
            [("a", vec!["b"]), ("b", vec!["a", "c"]), ("c", vec![])]
                .into_iter()
                .map(|(k, v)| (k.to_string(), v.into_iter().map(String::from).collect()))
                .collect();
        let big: Vec<BTreeSet<String>> = strongly_connected(&graph)
            .into_iter()
            .filter(|c| c.len() > 1)
            .collect();
        assert_eq!(big.len(), 1);
        assert!(big[0].contains("a") && big[0].contains("b"));
    }

    #[test]
    fn references_before_an_inline_module_belong_to_the_file() {
        let dir = std::env::temp_dir().join(format!("layout-test-{}", std::process::id()));
        let _ = fs::create_dir_all(&dir);
        let root = dir.join("lib.rs");
        fs::write(&root, "mod a;\nmod b;\n").unwrap();
        fs::write(
            dir.join("a.rs"),
            "use super::b::X;\n#[cfg(test)]\nmod tests {\n    use super::*;\n}\n",
        )
        .unwrap();
        fs::write(dir.join("b.rs"), "pub struct X;\nuse super::a;\n").unwrap();
        let tree = ModuleTree::load(&dir, &root).unwrap();
        let _ = fs::remove_dir_all(&dir);
        assert_eq!(
            tree.sibling_cycles(),
            vec!["crate: a -> {b}; b -> {a}".to_string()]
        );
    }
}

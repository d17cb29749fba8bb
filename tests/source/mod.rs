//! Reading `src/` as the structure tests do (`tests/layering.rs`, `tests/protocol_names.rs`):
//! its files, their code without comments and without test items, and where the files of the
//! modules a file declares are. One reader, so the tests agree on what "code" is.

use std::path::{Path, PathBuf};

pub fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable src") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// The text without comments (line, doc and block comments; string contents are kept, they
/// hold no paths worth reading).
pub fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let b = text.as_bytes();
    let (mut i, mut in_str) = (0, false);
    while i < b.len() {
        if in_str {
            if b[i] == b'\\' {
                out.push_str(&text[i..(i + 2).min(b.len())]);
                i += 2;
                continue;
            }
            in_str = b[i] != b'"';
        } else if b[i..].starts_with(b"//") {
            while i < b.len() && b[i] != b'\n' {
                i += 1;
            }
            continue;
        } else if b[i..].starts_with(b"/*") {
            let end = text[i..].find("*/").map_or(b.len(), |e| i + e + 2);
            i = end;
            continue;
        } else if b[i] == b'"' && (i == 0 || b[i - 1] != b'\'') {
            in_str = true;
        }
        let ch = text[i..].chars().next().expect("in bounds");
        out.push(ch);
        i += ch.len_utf8();
    }
    out
}

/// The text without `#[cfg(test)]` items (rustfmt layout: the item ends at the first line
/// that closes a brace at its indentation, or at its `;`), and the names of test modules kept
/// in files of their own (`#[cfg(test)] mod tests;`, maybe with `#[path = "…"]`).
pub fn strip_test_items(text: &str) -> (String, Vec<String>) {
    let lines: Vec<&str> = text.lines().collect();
    let (mut out, mut test_files) = (Vec::new(), Vec::new());
    let mut i = 0;
    while i < lines.len() {
        if lines[i].trim() != "#[cfg(test)]" {
            out.push(lines[i]);
            i += 1;
            continue;
        }
        let indent = &lines[i][..lines[i].len() - lines[i].trim_start().len()];
        let mut path = None;
        i += 1;
        while i < lines.len() && lines[i].trim_start().starts_with("#[") {
            let attr = lines[i].trim();
            if let Some(p) = attr.strip_prefix("#[path = \"") {
                path = p.strip_suffix("\"]").map(str::to_string);
            }
            i += 1;
        }
        let Some(item) = lines.get(i) else { break };
        if item.trim_end().ends_with(';') {
            if let Some(name) = item.trim().strip_prefix("mod ") {
                let name = name.trim_end_matches(';');
                test_files.push(path.unwrap_or_else(|| format!("{name}.rs")));
            }
            i += 1;
            continue;
        }
        let close = format!("{indent}}}");
        while i < lines.len() && !lines[i].starts_with(&close) {
            i += 1;
        }
        i += 1;
    }
    (out.join("\n"), test_files)
}

/// Where the files of modules declared in `file` are: beside it, or in its folder.
pub fn homes(file: &Path) -> [PathBuf; 2] {
    let parent = file.parent().expect("in a folder").to_path_buf();
    let own = if matches!(
        file.file_name().and_then(|n| n.to_str()),
        Some("mod.rs" | "lib.rs" | "main.rs")
    ) {
        parent.clone()
    } else {
        file.with_extension("")
    };
    [parent, own]
}

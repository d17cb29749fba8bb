//! No function in `src/` is longer than 70 lines (issue 39).
//! Reads rustfmt-formatted source: a function runs from its `fn` line to the first line after
//! it that closes a brace at the same indentation.

use std::path::{Path, PathBuf};

const LIMIT: usize = 70;

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable src") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// Whether `line` (without indentation) starts a function item.
fn starts_fn(line: &str) -> bool {
    let mut rest = line;
    for prefix in [
        "pub(crate) ",
        "pub(super) ",
        "pub ",
        "const ",
        "async ",
        "unsafe ",
    ] {
        rest = rest.strip_prefix(prefix).unwrap_or(rest);
    }
    rest.starts_with("fn ")
}

/// `(name, first line, length)` of every function in `text`.
fn functions(text: &str) -> Vec<(String, usize, usize)> {
    let lines: Vec<&str> = text.lines().collect();
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let trimmed = line.trim_start();
        if !starts_fn(trimmed) || trimmed.ends_with(';') {
            continue;
        }
        let indent = &line[..line.len() - trimmed.len()];
        let close = format!("{indent}}}");
        let end = lines[i..].iter().position(|l| {
            l.trim_end() == close
                || (l.starts_with(&close)
                    && l.len() > close.len()
                    && !l[close.len()..].starts_with(' '))
        });
        let Some(end) = end else { continue };
        let name = trimmed.split('(').next().unwrap_or(trimmed).to_string();
        found.push((name, i + 1, end + 1));
    }
    found
}

#[test]
fn no_function_in_src_is_longer_than_70_lines() {
    let mut files = Vec::new();
    rust_files(
        Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/src")),
        &mut files,
    );
    files.sort();
    let mut long = Vec::new();
    for file in &files {
        let text = std::fs::read_to_string(file).expect("readable file");
        for (name, line, len) in functions(&text) {
            if len > LIMIT {
                long.push(format!("{}:{line} {name}: {len} lines", file.display()));
            }
        }
    }
    assert!(
        long.is_empty(),
        "functions longer than {LIMIT} lines:\n{}",
        long.join("\n")
    );
}

#[test]
fn the_counter_sees_a_long_function_and_a_short_one() {
    let body = "    let x = 1;\n".repeat(95);
    let text = format!("fn short() {{\n}}\n\npub async fn long(a: u8) {{\n{body}}}\n");
    let found = functions(&text);
    assert_eq!(found.len(), 2);
    assert_eq!(found[0].2, 2);
    assert_eq!(found[1].2, 97);
}

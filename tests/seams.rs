//! The protocol seam, checked (issue 32): a driver returns what it read (`crate::sample`) and the
//! bus core counts. No file under a protocol's driver folder (`src/<protocol>/driver/`: every
//! `driver` folder one level under `src/`) names the counter (`Counter`, `CounterState`,
//! `CounterSpec`, `Update`, the `counter` module) or a `Reading`, so no protocol can count on
//! its own, and a new one has nothing of the counting to copy. Comments are not read;
//! `ChannelKind::Counter` (what a channel is, from the profile) is not the counter.

use std::path::{Path, PathBuf};

/// Names a driver must not use: the bus core's counting and what it builds.
const FORBIDDEN: &[&str] = &[
    "Counter",
    "CounterState",
    "CounterSpec",
    "Update",
    "Reading",
];

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable folder") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") {
            out.push(path);
        }
    }
}

/// The text without line and block comments.
fn strip_comments(text: &str) -> String {
    let mut out = String::with_capacity(text.len());
    let mut rest = text;
    while !rest.is_empty() {
        if let Some(after) = rest.strip_prefix("//") {
            rest = after.find('\n').map_or("", |n| &after[n..]);
        } else if let Some(after) = rest.strip_prefix("/*") {
            rest = after.find("*/").map_or("", |e| &after[e + 2..]);
        } else {
            let ch = rest.chars().next().expect("not empty");
            out.push(ch);
            rest = &rest[ch.len_utf8()..];
        }
    }
    out
}

/// What `text` (a driver's source) names of the counting: `(line, what)` for each use.
fn counting_named(text: &str) -> Vec<(usize, String)> {
    let mut found = Vec::new();
    for (n, line) in strip_comments(text).lines().enumerate() {
        let is_ident = |c: char| c.is_alphanumeric() || c == '_';
        let mut at = 0;
        while let Some(start) = line[at..].find(is_ident).map(|s| at + s) {
            let len = line[start..]
                .find(|c| !is_ident(c))
                .unwrap_or(line.len() - start);
            let word = &line[start..start + len];
            let is_kind = line[..start].ends_with("ChannelKind::") && word == "Counter";
            if FORBIDDEN.contains(&word) && !is_kind {
                found.push((n + 1, word.to_string()));
            } else if word == "counter" && line[start + len..].starts_with("::") {
                found.push((n + 1, "the counter module".to_string()));
            }
            at = start + len;
        }
    }
    found
}

#[test]
fn no_driver_names_the_counter_or_builds_a_reading() {
    let src = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/src"));
    let mut files = Vec::new();
    let mut drivers = 0;
    for entry in std::fs::read_dir(src).expect("src/ readable").flatten() {
        let driver = entry.path().join("driver");
        if driver.is_dir() {
            drivers += 1;
            rust_files(&driver, &mut files);
        }
    }
    files.sort();
    assert!(drivers >= 2, "every protocol's driver folder is read");
    assert!(files.len() > 3, "the drivers' files are read");
    let mut offences = Vec::new();
    for file in files {
        let text = std::fs::read_to_string(&file).expect("readable file");
        for (line, what) in counting_named(&text) {
            offences.push(format!("{}:{line}: {what}", file.display()));
        }
    }
    assert!(
        offences.is_empty(),
        "a driver returns samples (crate::sample) and the bus core counts; these count in a \
         driver:\n{}",
        offences.join("\n")
    );
}

#[test]
fn the_reader_finds_counting_in_code_and_not_in_comments_or_channel_kinds() {
    let text = "use crate::counter::CounterSpec;\n\
                // a Counter in a comment\n\
                let r = Reading { count, update };\n\
                if spec.kind == ChannelKind::Counter { ch.counter.update(count, at) }\n\
                /* Update */ let s = Sample::count(i, at, count, wrap);\n";
    let found = counting_named(text);
    let expected = [
        (1, "the counter module"),
        (1, "CounterSpec"),
        (3, "Reading"),
    ];
    assert_eq!(
        found,
        expected.map(|(n, w)| (n, w.to_string())),
        "a field or method named `counter`/`update` on a value is no path into the counter"
    );
}

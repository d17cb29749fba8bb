//! A format is named once: outside its own files and its config file, at most three files of
//! `src/` may name it (the module lists in `config/outputs/mod.rs` and `publish/mod.rs`, and
//! the output registry in `publish/formats.rs`). A format that leaks into
//! the core (the bus, the router, the MQTT task, the app) fails here, with the files that name
//! it. Comments and test code are not read.

use std::path::{Path, PathBuf};

/// A format, the files that are its own, and how code names it.
struct Format {
    name: &'static str,
    /// Paths under `src/` (a folder ends with `/`) that are the format's own, its config file
    /// among them.
    own: &'static [&'static str],
    /// Whether a line of code names it.
    names: fn(&str) -> bool,
}

const MOST_OTHER_FILES: usize = 3;

const FORMATS: &[Format] = &[
    Format {
        name: "sparkplug",
        own: &["publish/sparkplug/", "config/outputs/sparkplug.rs"],
        names: |line| line.to_ascii_lowercase().contains("sparkplug"),
    },
    Format {
        name: "homeassistant",
        own: &["publish/homeassistant/", "config/outputs/homeassistant.rs"],
        names: |line| {
            let l = line.to_ascii_lowercase();
            l.contains("homeassistant") || l.contains("home_assistant")
        },
    },
    Format {
        name: "json",
        own: &["publish/json.rs", "config/outputs/json.rs"],
        names: names_the_json_format,
    },
];

/// The JSON format by name: its type or kind (`Json`), its module (`mod json`, a path through
/// `json::` that is not `serde_json`'s). JSON the data format (`serde_json`, `to_json`, a
/// `--json` flag) is not the output format.
fn names_the_json_format(line: &str) -> bool {
    let words = line.split(|c: char| !(c.is_ascii_alphanumeric() || c == '_' || c == ':'));
    let mut words = words.filter(|w| !w.is_empty()).peekable();
    let mut previous = "";
    while let Some(w) = words.next() {
        let segments: Vec<&str> = w.split("::").collect();
        for (i, segment) in segments.iter().enumerate() {
            let path_through = *segment == "json" && i + 1 < segments.len();
            let before = if i == 0 { "" } else { segments[i - 1] };
            // `Json` the output format's type or kind, not another enum's variant (a log format).
            let json_type = *segment == "Json"
                && (matches!(before, "OutputKind" | "json") || i + 1 < segments.len());
            if json_type || (path_through && before != "serde_json") {
                return true;
            }
        }
        if previous == "mod" && w == "json" {
            return true;
        }
        previous = w;
        let _ = words.peek();
    }
    false
}

fn files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).unwrap() {
        let path = entry.unwrap().path();
        if path.is_dir() {
            files(&path, out);
        } else if path.extension().is_some_and(|e| e == "rs") {
            out.push(path);
        }
    }
}

/// Whether a file under `src/` is test code (tests beside what they test).
fn is_test_file(rel: &str) -> bool {
    rel.ends_with("_tests.rs") || rel.ends_with("/tests.rs")
}

/// The code of a file: comments, doc comments and `#[cfg(test)]` modules left out.
fn code_lines(text: &str) -> Vec<String> {
    let mut out = Vec::new();
    let mut lines = text.lines().peekable();
    while let Some(line) = lines.next() {
        let trimmed = line.trim_start();
        if trimmed.starts_with("#[cfg(test)]") {
            // The item after it: a `mod … {` block to its closing brace at the same indent, or
            // one line.
            if let Some(next) = lines.next()
                && next.trim_end().ends_with('{')
            {
                let indent = next.len() - next.trim_start().len();
                for l in lines.by_ref() {
                    if l.len() - l.trim_start().len() == indent && l.trim() == "}" {
                        break;
                    }
                }
            }
            continue;
        }
        if trimmed.starts_with("//") {
            continue;
        }
        let code = match line.find("//") {
            Some(i) if !line[..i].contains('"') => &line[..i],
            _ => line,
        };
        out.push(code.to_string());
    }
    out
}

/// The files of `src/` (relative, with `/`) that name `format` outside its own files.
fn naming_files(src: &Path, format: &Format) -> Vec<String> {
    let mut all = Vec::new();
    files(src, &mut all);
    let mut out = Vec::new();
    for path in all {
        let rel = path
            .strip_prefix(src)
            .unwrap()
            .to_string_lossy()
            .replace('\\', "/");
        if is_test_file(&rel) || format.own.iter().any(|own| rel.starts_with(own)) {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        if code_lines(&text).iter().any(|l| (format.names)(l)) {
            out.push(rel);
        }
    }
    out.sort();
    out
}

#[test]
fn no_format_is_named_in_more_than_three_files_outside_its_own() {
    let src = Path::new(env!("CARGO_MANIFEST_DIR")).join("src");
    let mut leaks = Vec::new();
    for f in FORMATS {
        let files = naming_files(&src, f);
        println!("{}: {}", f.name, files.join(", "));
        if files.len() > MOST_OTHER_FILES {
            leaks.push(format!("{} is named in {}", f.name, files.join(", ")));
        }
    }
    assert!(
        leaks.is_empty(),
        "formats leak into the core:\n{}",
        leaks.join("\n")
    );
}

#[test]
fn the_check_sees_a_format_named_in_code_and_not_in_comments_or_tests() {
    let text = "// Sparkplug in a comment\nuse crate::publish::sparkplug::Node; // here\n#[cfg(test)]\nmod tests {\n    use sparkplug;\n}\n";
    let lines = code_lines(text);
    assert_eq!(lines, ["use crate::publish::sparkplug::Node; "]);
    assert!(names_the_json_format("let j = super::json::Json::new(c);"));
    assert!(names_the_json_format("OutputKind::Json => 1,"));
    assert!(!names_the_json_format("serde_json::json!({})"));
    assert!(!names_the_json_format("let v = serde_json::to_string(&x);"));
    assert!(names_the_json_format("pub mod json;"));
    assert!(names_the_json_format("Box::new(Json::new(c))"));
    assert!(!names_the_json_format(
        "LogFormat::Json => builder.json().init(),"
    ));
    assert!(!names_the_json_format("fn to_json(&self) {}"));
    assert!(!is_test_file("publish/mqtt.rs"));
    assert!(is_test_file("publish/mqtt_tests.rs"));
}

/// The encoder every format implements (`publish/format.rs`) knows no transport: no MQTT hook
/// (subscriptions, wills, connections, holds) and no command router; those are a format's
/// `Lifecycle` (`publish/lifecycle.rs`), which only the formats on an MQTT connection have.
#[test]
fn the_encoder_trait_knows_no_transport_and_no_router() {
    let path = Path::new(env!("CARGO_MANIFEST_DIR")).join("src/publish/format.rs");
    let text = std::fs::read_to_string(path).unwrap();
    let forbidden = [
        "dispatch",
        "Incoming",
        "Will",
        "mqtt",
        "subscri",
        "connected",
        "Reaction",
    ];
    for line in code_lines(&text) {
        for word in forbidden {
            assert!(
                !line.contains(word),
                "publish/format.rs names {word:?}: {line}"
            );
        }
    }
}

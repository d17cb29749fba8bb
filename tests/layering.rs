//! The floors of `src/`, written down and checked (the way `tests/function_length.rs` keeps
//! functions short): which top-level module may `use` which, and no import circle between
//! files. A `crate::…` (or `super::…`) path against [`FLOORS`] fails, and so does any circle of
//! files that import each other. Comments and `#[cfg(test)]` items are not read. The same
//! table, with the direction of the floors, is in docs/architecture.md.

use std::collections::{BTreeMap, BTreeSet};
use std::path::{Path, PathBuf};

mod source;
use source::{homes, rust_files, strip_comments, strip_test_items};

/// What each part of `src/` may use, lowest floors first. A part is a top-level module, except
/// in a protocol's own folder (`src/modbus/`, `src/mbus/`: a top-level module with a driver
/// row): each of its parts sits at the floor of the layer it implements, as a piece of that
/// layer ([`LAYERS`]: `modbus::config` is `config`, `modbus::server` is `publish`,
/// `mbus::sim` is `sim`), and its driver is a part of its own (`modbus::driver`; the M-Bus
/// protocol layer `mbus::driver`, pure, and the M-Bus driver on it `mbus::driver::master`):
/// only the parts listed here may know a protocol's driver. A part may always use itself. A
/// new module needs a row (and a floor).
const FLOORS: &[(&str, &[&str])] = &[
    // Vocabulary: pure values and rules used everywhere.
    ("topics", &[]),
    ("event", &[]),
    ("decimal", &[]),
    ("health", &[]),
    ("log_budget", &[]),
    ("bus_health", &[]),
    ("signing", &[]),
    ("metering", &["decimal", "event", "signing"]),
    ("counter", &["event", "metering"]),
    ("profile", &["topics"]),
    ("decode", &["profile"]),
    // The checked configuration.
    (
        "config",
        &[
            "counter", "decimal", "metering", "profile", "signing", "topics",
        ],
    ),
    ("report", &["config", "profile"]),
    ("state", &["config", "counter"]),
    ("boot", &["config", "state"]),
    ("billing_report", &["config", "state", "metering"]),
    ("systemd", &["health"]),
    // Commands and what becomes of them; the events a bus sends.
    ("command", &["decimal", "topics"]),
    ("outcome", &["command"]),
    ("admission", &["command"]),
    ("dedupe", &["outcome"]),
    ("scan", &["command", "outcome"]),
    (
        "reading",
        &[
            "bus_health",
            "command",
            "config",
            "counter",
            "decimal",
            "metering",
            "outcome",
            "profile",
        ],
    ),
    (
        "metrics",
        &[
            "bus_health",
            "config",
            "health",
            "outcome",
            "profile",
            "reading",
        ],
    ),
    // What a driver hands the core: raw samples and the channels they belong to.
    ("sample", &["config", "counter", "profile", "reading"]),
    // The protocol-neutral bus core (it counts), then the protocols under it (they never do).
    (
        "bus",
        &[
            "bus_health",
            "command",
            "config",
            "counter",
            "decimal",
            "event",
            "health",
            "log_budget",
            "metering",
            "metrics",
            "profile",
            "reading",
            "sample",
            "state",
        ],
    ),
    (
        "modbus::driver",
        &[
            "bus",
            "bus_health",
            "command",
            "config",
            "decode",
            "outcome",
            "profile",
            "reading",
            "sample",
            "scan",
            "state",
            "topics",
        ],
    ),
    // The M-Bus protocol layer: pure frames and records, standing on nothing of ours.
    ("mbus::driver", &[]),
    // The M-Bus master on it: the driver (it reads; the core counts).
    (
        "mbus::driver::master",
        &[
            "bus",
            "bus_health",
            "command",
            "config",
            "decimal",
            "mbus::driver",
            "outcome",
            "profile",
            "reading",
            "sample",
            "scan",
            "state",
        ],
    ),
    // Commands in, messages out.
    // A pushed config: read, guarded, watched (pure).
    ("remote", &["config", "signing"]),
    (
        "dispatch",
        &[
            "admission",
            "bus",
            "command",
            "config",
            "dedupe",
            "log_budget",
            "outcome",
            "reading",
            "remote",
            "scan",
            "topics",
        ],
    ),
    ("outbox", &["topics"]),
    // The status board: every event the outputs get, and what the page reads of health and
    // the metrics.
    (
        "status",
        &[
            "bus_health",
            "config",
            "event",
            "health",
            "metering",
            "metrics",
            "outcome",
            "profile",
            "reading",
        ],
    ),
    (
        "publish",
        &[
            "boot",
            "command",
            "config",
            "counter",
            "dispatch",
            "event",
            "health",
            "log_budget",
            "metering",
            "metrics",
            "outbox",
            "outcome",
            "profile",
            "reading",
            "signing",
            "state",
            "status",
            "topics",
        ],
    ),
    // The HTTP endpoint: metrics, health and the status page.
    (
        "http",
        &["config", "health", "log_budget", "metrics", "status"],
    ),
    // Tools and wiring on top.
    (
        "commission",
        &[
            "bus",
            "command",
            "config",
            "mbus::driver",
            "mbus::driver::master",
            "modbus::driver",
            "outcome",
            "profile",
            "publish",
        ],
    ),
    ("sim", &["decode", "modbus::driver", "profile"]),
    // The protocols' registry: a bus's driver, a commissioning command and the serving
    // outputs, by protocol.
    (
        "protocols",
        &[
            "bus",
            "command",
            "commission",
            "config",
            "health",
            "mbus::driver::master",
            "metrics",
            "modbus::driver",
            "profile",
            "publish",
            "scan",
            "sim",
        ],
    ),
    ("setreading", &["config", "decimal", "publish", "topics"]),
    ("verify", &["config", "publish", "signing", "topics"]),
    (
        "app",
        &[
            "boot",
            "bus",
            "command",
            "config",
            "dispatch",
            "health",
            "http",
            "metrics",
            "outcome",
            "protocols",
            "publish",
            "reading",
            "remote",
            "scan",
            "state",
            "status",
            "systemd",
            "topics",
        ],
    ),
    ("demo", &["app", "config", "report", "sim"]),
];

/// One file of `src/`: its module path (`["bus", "device"]`) and what it imports.
struct Source {
    module: Vec<String>,
    file: PathBuf,
    text: String,
}

/// `src/bus/mod.rs` → `["bus"]`; `src/lib.rs` and `src/main.rs` → `[]`.
fn module_of(src: &Path, file: &Path) -> Vec<String> {
    let rel = file
        .strip_prefix(src)
        .expect("under src")
        .with_extension("");
    let mut parts: Vec<String> = rel
        .components()
        .map(|c| c.as_os_str().to_string_lossy().into_owned())
        .collect();
    if matches!(
        parts.last().map(String::as_str),
        Some("mod" | "lib" | "main")
    ) {
        parts.pop();
    }
    parts
}

/// Every path a file names: `use` trees expanded (`crate::{a::b, c}` → `crate::a::b`,
/// `crate::c`), and paths written inline (`crate::x::y(…)`).
fn paths(text: &str) -> Vec<Vec<String>> {
    let mut found = Vec::new();
    let mut offset = 0;
    for line in text.split_inclusive('\n') {
        let trimmed = line.trim_start();
        let body = ["use ", "pub use ", "pub(crate) use ", "pub(super) use "]
            .iter()
            .find_map(|p| trimmed.strip_prefix(p));
        if let Some(body) = body {
            let start = offset + (line.len() - body.len());
            if let Some(end) = text[start..].find(';') {
                let tree = text[start..start + end]
                    .split_whitespace()
                    .collect::<Vec<_>>();
                expand(&tree.join(" "), &[], &mut found);
            }
        }
        offset += line.len();
    }
    for start in ["crate::", "super::", "self::"] {
        for (at, _) in text.match_indices(start) {
            let before = text[..at].chars().last();
            if before.is_some_and(|c| c.is_alphanumeric() || c == '_') {
                continue;
            }
            found.push(inline_path(&text[at..]));
        }
    }
    found
}

/// The path at the start of `text`: identifiers joined by `::`.
fn inline_path(text: &str) -> Vec<String> {
    let mut path = Vec::new();
    let mut rest = text;
    loop {
        let len = rest
            .find(|c: char| !(c.is_alphanumeric() || c == '_'))
            .unwrap_or(rest.len());
        if len == 0 {
            break;
        }
        path.push(rest[..len].to_string());
        match rest[len..].strip_prefix("::") {
            Some(next) => rest = next,
            None => break,
        }
    }
    path
}

/// Expands one `use` tree under `prefix`.
fn expand(tree: &str, prefix: &[String], out: &mut Vec<Vec<String>>) {
    let tree = tree.trim();
    let split = |t: &str| -> Vec<String> {
        t.split("::")
            .map(str::trim)
            .filter(|s| !s.is_empty())
            .map(String::from)
            .collect()
    };
    let Some(open) = tree.find('{') else {
        let mut path = prefix.to_vec();
        path.extend(split(tree.split(" as ").next().unwrap_or(tree)));
        out.push(path);
        return;
    };
    let mut path = prefix.to_vec();
    path.extend(split(&tree[..open]));
    let inner = &tree[open + 1..tree.rfind('}').unwrap_or(tree.len())];
    let (mut depth, mut from) = (0, 0);
    for (i, c) in inner.char_indices() {
        match c {
            '{' => depth += 1,
            '}' => depth -= 1,
            ',' if depth == 0 => {
                expand(&inner[from..i], &path, out);
                from = i + 1;
            }
            _ => {}
        }
    }
    if !inner[from..].trim().is_empty() {
        expand(&inner[from..], &path, out);
    }
}

/// The module of `src/` a path names (the longest prefix that is a file), seen from `from`.
fn resolve(
    path: &[String],
    from: &[String],
    modules: &BTreeSet<Vec<String>>,
) -> Option<Vec<String>> {
    let (mut base, mut segs): (Vec<String>, &[String]) = match path.first()?.as_str() {
        "crate" => (Vec::new(), &path[1..]),
        "self" => (from.to_vec(), &path[1..]),
        "super" => (from.to_vec(), path),
        _ => return None,
    };
    while segs.first().is_some_and(|s| s == "super") {
        base.pop();
        segs = &segs[1..];
    }
    base.extend(segs.iter().cloned());
    (1..=base.len())
        .rev()
        .map(|n| base[..n].to_vec())
        .find(|m| modules.contains(m))
}

/// The layers a protocol's own folder implements, by the name of its child, and the part of
/// the table each belongs to: a protocol's config is part of `config`, its server output of
/// `publish`, its commissioning of `commission`, its simulator of `sim`. Its `driver` is a
/// part of its own (a row named `<protocol>::driver`, which is what makes a top-level module
/// a protocol's folder).
const LAYERS: &[(&str, &str)] = &[
    ("config", "config"),
    ("server", "publish"),
    ("commission", "commission"),
    ("sim", "sim"),
];

/// Whether a row of the table is named `name`.
fn has_row(name: &str) -> bool {
    FLOORS.iter().any(|(p, _)| *p == name)
}

/// The part of the table a module belongs to.
fn part(module: &[String]) -> String {
    match module {
        [] => "lib".into(),
        // A protocol's folder itself only declares its parts.
        [p] if has_row(&format!("{p}::driver")) => "lib".into(),
        [p, layer, rest @ ..] if has_row(&format!("{p}::driver")) => {
            if layer == "driver" {
                let inner = rest.first().map(|r| format!("{p}::driver::{r}"));
                return inner
                    .filter(|r| has_row(r))
                    .unwrap_or_else(|| format!("{p}::driver"));
            }
            LAYERS
                .iter()
                .find(|(l, _)| l == layer)
                .map_or_else(|| format!("{p}::{layer}"), |(_, at)| at.to_string())
        }
        [top, ..] => top.clone(),
    }
}

/// The files of the modules `text` declares (`mod x;`, maybe with `#[path = "…"]`).
fn declared(text: &str) -> Vec<String> {
    let mut path = None;
    let mut out = Vec::new();
    for line in text.lines().map(str::trim) {
        if let Some(p) = line.strip_prefix("#[path = \"") {
            path = p.strip_suffix("\"]").map(str::to_string);
        } else if let Some(name) = line.strip_prefix("mod ").and_then(|l| l.strip_suffix(';')) {
            out.push(path.take().unwrap_or_else(|| format!("{name}.rs")));
        } else if !line.starts_with("#[") {
            path = None;
        }
    }
    out
}

/// Every non-test file of `src/` with its text (comments and test items removed). A test
/// module's file, and every file it declares in turn, is not read.
fn sources() -> Vec<Source> {
    let src = Path::new(concat!(env!("CARGO_MANIFEST_DIR"), "/src"));
    let mut files = Vec::new();
    rust_files(src, &mut files);
    files.sort();
    let mut tests = BTreeSet::new();
    let mut out = Vec::new();
    for file in files {
        let raw = std::fs::read_to_string(&file).expect("readable file");
        let (text, test_files) = strip_test_items(&strip_comments(&raw));
        for t in test_files {
            tests.extend(homes(&file).map(|h| h.join(&t)));
        }
        out.push((
            Source {
                module: module_of(src, &file),
                file,
                text,
            },
            raw,
        ));
    }
    loop {
        let more: Vec<PathBuf> = out
            .iter()
            .filter(|(s, _)| tests.contains(&s.file))
            .flat_map(|(s, raw)| {
                let homes = homes(&s.file);
                declared(raw)
                    .into_iter()
                    .flat_map(move |d| homes.clone().map(|h| h.join(&d)))
            })
            .filter(|f| !tests.contains(f))
            .collect();
        if more.is_empty() {
            break;
        }
        tests.extend(more);
    }
    out.into_iter()
        .map(|(s, _)| s)
        .filter(|s| !tests.contains(&s.file))
        .collect()
}

/// File → the files it imports (other than itself), its own child modules named bare
/// (`use child::X;`, `child::f()`) included: a parent and a child that use each other are a
/// circle of files too.
fn imports(sources: &[Source]) -> BTreeMap<Vec<String>, BTreeSet<Vec<String>>> {
    let modules: BTreeSet<Vec<String>> = sources.iter().map(|s| s.module.clone()).collect();
    sources
        .iter()
        .map(|s| {
            let mut to: BTreeSet<Vec<String>> = paths(&s.text)
                .iter()
                .filter_map(|p| resolve(p, &s.module, &modules))
                .filter(|m| *m != s.module && !m.is_empty())
                .collect();
            let children = modules
                .iter()
                .filter(|m| m.len() == s.module.len() + 1 && m.starts_with(&s.module));
            to.extend(
                children
                    .filter(|c| names_bare(&s.text, &c[c.len() - 1]))
                    .cloned(),
            );
            (s.module.clone(), to)
        })
        .collect()
}

/// Whether `text` names the module `name` at the start of a path (`name::…`, not `x::name::`).
fn names_bare(text: &str, name: &str) -> bool {
    text.match_indices(&format!("{name}::")).any(|(at, _)| {
        !text[..at]
            .chars()
            .last()
            .is_some_and(|c| c.is_alphanumeric() || c == '_' || c == ':')
    })
}

/// Circles of files that import each other (strongly connected components of two or more).
fn circles(edges: &BTreeMap<Vec<String>, BTreeSet<Vec<String>>>) -> Vec<Vec<String>> {
    let nodes: Vec<&Vec<String>> = edges.keys().collect();
    let reach = |from: &Vec<String>| {
        let mut seen = BTreeSet::new();
        let mut todo = vec![from.clone()];
        while let Some(n) = todo.pop() {
            for m in edges.get(&n).into_iter().flatten() {
                if seen.insert(m.clone()) {
                    todo.push(m.clone());
                }
            }
        }
        seen
    };
    let reached: BTreeMap<&Vec<String>, BTreeSet<Vec<String>>> =
        nodes.iter().map(|n| (*n, reach(n))).collect();
    let mut done = BTreeSet::new();
    let mut out = Vec::new();
    for n in &nodes {
        if done.contains(*n) || !reached[n].contains(*n) {
            continue;
        }
        let circle: Vec<String> = nodes
            .iter()
            .filter(|m| reached[n].contains(**m) && reached[**m].contains(*n))
            .map(|m| {
                done.insert((*m).clone());
                m.join("/")
            })
            .collect();
        out.push(circle);
    }
    out
}

/// Uses that run against [`FLOORS`], as `file: part → part (path)`.
fn against_the_floors(sources: &[Source]) -> Vec<String> {
    let table: BTreeMap<&str, &[&str]> = FLOORS.iter().copied().collect();
    let edges = imports(sources);
    let mut bad = Vec::new();
    for s in sources {
        let from = part(&s.module);
        if from == "lib" {
            continue;
        }
        let Some(allowed) = table.get(from.as_str()) else {
            bad.push(format!(
                "{}: module {from} has no row in FLOORS (give it a floor)",
                s.file.display()
            ));
            continue;
        };
        for to in &edges[&s.module] {
            let to = part(to);
            if to != from && !allowed.contains(&to.as_str()) {
                bad.push(format!(
                    "{}: {from} may not use {to} (FLOORS allows {allowed:?})",
                    s.file.display()
                ));
            }
        }
    }
    bad.sort();
    bad.dedup();
    bad
}

#[test]
fn every_use_in_src_follows_the_floors() {
    let bad = against_the_floors(&sources());
    assert!(
        bad.is_empty(),
        "uses against the floors:\n{}",
        bad.join("\n")
    );
}

#[test]
fn no_files_of_src_import_each_other_in_a_circle() {
    let found = circles(&imports(&sources()));
    let text: Vec<String> = found.iter().map(|c| c.join(" ↔ ")).collect();
    assert!(found.is_empty(), "import circles:\n{}", text.join("\n"));
}

#[test]
fn the_floors_themselves_have_a_direction() {
    let table: BTreeMap<Vec<String>, BTreeSet<Vec<String>>> = FLOORS
        .iter()
        .map(|(from, to)| {
            (
                vec![from.to_string()],
                to.iter().map(|t| vec![t.to_string()]).collect(),
            )
        })
        .collect();
    assert!(circles(&table).is_empty(), "{:?}", circles(&table));
    for (from, to) in FLOORS {
        for t in *to {
            assert!(
                FLOORS.iter().any(|(p, _)| p == t),
                "{from} may use {t}, which has no row"
            );
        }
    }
}

#[test]
fn the_reader_sees_use_trees_inline_paths_and_skips_comments_and_tests() {
    let text = "use crate::{a::{b, c as d}, e};\n// use crate::hidden;\nfn f() { crate::g::h(); super::i::j; }\n#[cfg(test)]\nmod tests {\n    use crate::test_only;\n}\n";
    let (kept, _) = strip_test_items(&strip_comments(text));
    let seen: BTreeSet<String> = paths(&kept).iter().map(|p| p.join("::")).collect();
    for want in [
        "crate::a::b",
        "crate::a::c",
        "crate::e",
        "crate::g::h",
        "super::i::j",
    ] {
        assert!(seen.contains(want), "{want} in {seen:?}");
    }
    assert!(
        !seen
            .iter()
            .any(|p| p.contains("hidden") || p.contains("test_only"))
    );
    let from = vec!["bus".to_string(), "device".to_string()];
    let modules: BTreeSet<Vec<String>> = [vec!["bus".to_string()], vec!["i".to_string()]]
        .into_iter()
        .collect();
    let path: Vec<String> = ["super", "super", "i", "j"].map(String::from).into();
    assert_eq!(resolve(&path, &from, &modules), Some(vec!["i".to_string()]));
}

#[test]
fn a_parent_and_a_child_that_use_each_other_are_a_circle() {
    let src = |module: &[&str], text: &str| Source {
        module: module.iter().map(|m| m.to_string()).collect(),
        file: PathBuf::from("x.rs"),
        text: text.into(),
    };
    let sources = [
        src(&["outbox"], "mod chatter;\nuse chatter::Chatter;"),
        src(&["outbox", "chatter"], "use super::Message;"),
    ];
    assert_eq!(circles(&imports(&sources)).len(), 1);
    let apart = [
        src(&["outbox"], "mod chatter;\nuse chatter::Chatter;"),
        src(&["outbox", "chatter"], "use std::fmt;"),
    ];
    assert!(circles(&imports(&apart)).is_empty());
}

#[test]
fn a_use_against_the_floors_and_a_circle_are_both_found() {
    let src = |module: &[&str], text: &str| Source {
        module: module.iter().map(|s| s.to_string()).collect(),
        file: PathBuf::from(module.join("/")),
        text: text.into(),
    };
    let sources = [
        src(&["counter"], "use crate::app::run;"),
        src(&["app"], ""),
        src(&["bus", "a"], "use super::b::X;"),
        src(&["bus", "b"], "use super::a::Y;"),
    ];
    let bad = against_the_floors(&sources);
    assert_eq!(bad.len(), 1, "{bad:?}");
    assert!(bad[0].contains("counter may not use app"), "{bad:?}");
    let found = circles(&imports(&sources));
    assert_eq!(found, [vec!["bus/a".to_string(), "bus/b".to_string()]]);
}

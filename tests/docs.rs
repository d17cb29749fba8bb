//! The documentation keeps up with the code: every key the example config documents has its
//! place in the configuration page, and the README stays a front door whose links lead
//! somewhere.

use std::collections::BTreeSet;
use std::path::Path;

fn read(path: &str) -> String {
    let full = Path::new(env!("CARGO_MANIFEST_DIR")).join(path);
    std::fs::read_to_string(&full).unwrap_or_else(|e| panic!("{}: {e}", full.display()))
}

/// The keys of the example config, set or shown commented out (`# key = value`).
fn example_keys() -> BTreeSet<String> {
    let mut keys = BTreeSet::new();
    for line in read("config/pulsegate.example.toml").lines() {
        let line = line.trim_start_matches('#').trim();
        if line.starts_with('[') {
            continue;
        }
        let Some((key, _)) = line.split_once('=') else {
            continue;
        };
        let key = key.trim();
        let is_key = !key.is_empty()
            && key
                .chars()
                .all(|c| c.is_ascii_lowercase() || c.is_ascii_digit() || c == '_' || c == '.');
        if is_key && key.starts_with(|c: char| c.is_ascii_lowercase()) {
            // `channels.enc0 = {…}`: the key is `channels`, `enc0` a name of the example's.
            keys.insert(key.split('.').next().unwrap().to_string());
        }
    }
    keys
}

#[test]
fn every_key_of_the_example_config_is_in_the_configuration_page() {
    let page = read("docs/configuration.md");
    let keys = example_keys();
    assert!(keys.len() > 40, "found only {keys:?}");
    let missing: Vec<&String> = keys
        .iter()
        .filter(|k| !page.contains(&format!("`{k}`")))
        .collect();
    assert!(
        missing.is_empty(),
        "keys of config/pulsegate.example.toml not in docs/configuration.md: {missing:?}"
    );
}

#[test]
fn the_readme_is_a_front_door_whose_links_lead_somewhere() {
    let readme = read("README.md");
    assert!(
        readme.lines().count() <= 300,
        "the README grew past 300 lines"
    );
    let mut pages = 0;
    for target in readme
        .split("](")
        .skip(1)
        .filter_map(|s| s.split(')').next())
    {
        if target.starts_with("http") || target.starts_with('#') {
            continue;
        }
        let path = target.split('#').next().unwrap();
        assert!(
            Path::new(env!("CARGO_MANIFEST_DIR")).join(path).exists(),
            "the README links to {target}, which is not there"
        );
        pages += usize::from(path.starts_with("docs/"));
    }
    assert!(pages >= 10, "the README links {pages} reference pages");
}

#[test]
fn links_between_the_reference_pages_lead_somewhere() {
    let docs = Path::new(env!("CARGO_MANIFEST_DIR")).join("docs");
    for entry in std::fs::read_dir(&docs).unwrap() {
        let path = entry.unwrap().path();
        if path.extension().is_none_or(|e| e != "md") {
            continue;
        }
        let text = std::fs::read_to_string(&path).unwrap();
        for target in text.split("](").skip(1).filter_map(|s| s.split(')').next()) {
            if target.starts_with("http") || target.starts_with('#') || target.contains(' ') {
                continue;
            }
            let file = target.split('#').next().unwrap();
            assert!(
                docs.join(file).exists(),
                "{} links to {target}, which is not there",
                path.display()
            );
        }
    }
}

/// Every file docs/architecture.md names (a backticked `name.rs`, or one in its tree drawing)
/// exists: as a path from the repository or from `src/`, or, for a bare file name written
/// in a folder's paragraph, as a file of that name somewhere under `src/` or `tests/` (a
/// pattern such as `*_tests.rs` is not a name).
#[test]
fn the_architecture_names_only_files_that_exist() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    let mut stack = vec![root.join("src"), root.join("tests"), root.join("benches")];
    while let Some(dir) = stack.pop() {
        for e in std::fs::read_dir(&dir).unwrap().flatten() {
            let p = e.path();
            if p.is_dir() {
                stack.push(p);
            } else {
                files.push(p.strip_prefix(root).unwrap().display().to_string());
            }
        }
    }
    let text = read("docs/architecture.md");
    let named: BTreeSet<String> = text
        .split(|c: char| !(c.is_ascii_alphanumeric() || "_/.-".contains(c)))
        .filter(|w| w.ends_with(".rs") && w.len() > 3 && !w.starts_with('_'))
        .map(|w| w.trim_start_matches("./").to_string())
        .collect();
    let missing: Vec<&String> = named
        .iter()
        .filter(|n| {
            !root.join(n).exists()
                && !root.join("src").join(n).exists()
                && !files.iter().any(|f| f.ends_with(&format!("/{n}")))
        })
        .collect();
    assert!(
        missing.is_empty(),
        "docs/architecture.md names files that do not exist: {missing:?}"
    );
}

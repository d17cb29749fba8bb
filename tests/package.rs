//! The production build stays lean: the Debian package (`cargo deb`, default features) carries
//! no embedded broker, the README's crate count stays true, and the README's first command (the
//! demo) names a feature that exists.

use std::path::PathBuf;
use std::process::Command;

fn repo() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn read(rel: &str) -> String {
    let path = repo().join(rel);
    std::fs::read_to_string(&path).unwrap_or_else(|e| panic!("reading {}: {e}", path.display()))
}

fn manifest() -> toml::Table {
    read("Cargo.toml").parse().expect("Cargo.toml parses")
}

/// Every crate (`name version`) of the normal dependency tree built with `args`.
fn crates(args: &[&str]) -> Vec<String> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let out = Command::new(cargo)
        .current_dir(repo())
        .args(["tree", "-e", "normal", "--prefix", "none", "-f", "{p}"])
        .args(args)
        .output()
        .expect("cargo tree runs");
    assert!(
        out.status.success(),
        "cargo tree: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    let mut list: Vec<String> = String::from_utf8_lossy(&out.stdout)
        .lines()
        .filter_map(|l| {
            let mut w = l.split_whitespace();
            Some(format!("{} {}", w.next()?, w.next()?))
        })
        .collect();
    list.sort();
    list.dedup();
    list
}

/// The cargo arguments `cargo deb` builds with: its `features` and `default-features` keys.
fn package_build_args() -> Vec<String> {
    let m = manifest();
    let deb = m["package"]["metadata"]["deb"].as_table().unwrap();
    let mut args = Vec::new();
    if deb.get("default-features").and_then(|v| v.as_bool()) == Some(false) {
        args.push("--no-default-features".to_string());
    }
    if let Some(f) = deb.get("features").and_then(|v| v.as_array()) {
        let names: Vec<&str> = f.iter().filter_map(|v| v.as_str()).collect();
        args.push(format!("--features={}", names.join(",")));
    }
    args
}

#[test]
fn the_package_build_has_no_embedded_broker() {
    let args = package_build_args();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let tree = crates(&args);
    let brokers: Vec<&String> = tree
        .iter()
        .filter(|c| c.starts_with("rumqttd ") || c.starts_with("axum "))
        .collect();
    assert!(brokers.is_empty(), "the package build carries {brokers:?}");
}

#[test]
fn the_deployment_page_gives_the_package_crate_count() {
    let args = package_build_args();
    let args: Vec<&str> = args.iter().map(String::as_str).collect();
    let count = crates(&args).len();
    let readme = read("docs/deployment.md");
    let stated: usize = readme
        .split("crates in the package build")
        .next()
        .and_then(|before| before.split_whitespace().last())
        .and_then(|n| n.parse().ok())
        .expect("docs/deployment.md says `N crates in the package build`");
    // Within 10%: the figure is for orientation, a patch release upstream must not break it.
    assert!(
        stated.abs_diff(count) * 10 <= count,
        "docs/deployment.md says {stated} crates in the package build, cargo tree counts {count}"
    );
}

#[test]
fn the_readme_starts_with_the_demo_and_the_test_command() {
    let readme = read("README.md");
    let block = readme
        .split("```sh\n")
        .nth(1)
        .and_then(|b| b.split("```").next())
        .expect("a first sh block");
    let commands: Vec<&str> = block
        .lines()
        .map(|l| l.split('#').next().unwrap().trim())
        .collect();
    assert_eq!(commands.len(), 2, "{block}");
    assert!(commands[0].ends_with("-- demo"), "{}", commands[0]);
    assert_eq!(commands[1], "scripts/test");
    // The broker is opt-in, so the demo command must turn it on.
    let m = manifest();
    let default = m["features"]["default"].as_array().unwrap();
    assert!(
        !default
            .iter()
            .any(|f| f.as_str() == Some("embedded-broker")),
        "the embedded broker is a default feature again: {default:?}"
    );
    assert!(
        commands[0].contains("--features embedded-broker"),
        "{}",
        commands[0]
    );
}

/// The packaged binary has no broker: `demo` without `--mqtt` says how to get one.
#[cfg(not(feature = "embedded-broker"))]
#[test]
fn the_lean_demo_without_a_broker_names_both_ways_to_get_one() {
    let out = Command::new(env!("CARGO_BIN_EXE_pulsegate"))
        .args(["demo", "--duration", "1s"])
        .output()
        .unwrap();
    assert!(!out.status.success());
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        err.contains("--mqtt HOST:PORT") && err.contains("--features embedded-broker"),
        "{err}"
    );
}

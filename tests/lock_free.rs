//! The router, health and the status board are plain values with thin shells (issue 39): no
//! `Mutex` or `RwLock` in their code, so no lock hub grows back where state machines live.

use std::path::{Path, PathBuf};

/// Where the router, health and the status board live.
const PLAIN: &[&str] = &[
    "src/dispatch.rs",
    "src/dispatch",
    "src/health",
    "src/status",
];

fn files(path: &Path, out: &mut Vec<PathBuf>) {
    if path.is_dir() {
        for entry in std::fs::read_dir(path).expect("readable") {
            files(&entry.expect("entry").path(), out);
        }
    } else if path.extension().is_some_and(|e| e == "rs") {
        out.push(path.to_path_buf());
    }
}

#[test]
fn the_router_health_and_status_code_holds_no_lock() {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut all = Vec::new();
    for p in PLAIN {
        files(&root.join(p), &mut all);
    }
    assert!(all.len() >= 8, "the files moved? {all:?}");
    let mut locks = Vec::new();
    for file in &all {
        let text = std::fs::read_to_string(file).expect("readable");
        for (n, line) in text.lines().enumerate() {
            let code = line.split("//").next().unwrap_or("");
            if code.contains("Mutex") || code.contains("RwLock") {
                locks.push(format!("{}:{}: {}", file.display(), n + 1, line.trim()));
            }
        }
    }
    assert!(
        locks.is_empty(),
        "locks in plain-value code:\n{}",
        locks.join("\n")
    );
}

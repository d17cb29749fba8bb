//! Literal sleeps in `tests/` are counted and may only shrink: issue 39 asks for at most 100 s
//! ([`GOAL_MS`]), and the count stays there; [`RATCHET_MS`] is what it stands at, lowered with
//! every change that removes sleeps, so a new one has to pay for itself. A test that waits in
//! real time needs a reason, and what can run on tokio's paused clock does.
//!
//! How a sleep is counted (a literal count, not a measurement):
//! - A sleep is a call of `sleep(` or `sleep_until(` (tokio's or std's). It costs the sum of the
//!   `Duration::from_secs(N)`, `from_millis(N)`, `from_micros(N)` and `from_secs_f64(X)` literals
//!   written in its argument (an expression in one, `from_millis(500 + next() % 1500)`, costs the
//!   sum of its numbers: a bound).
//! - A sleep inside a loop counts once: the count is of what is written, not of how often it runs
//!   (a poll loop's 20 ms is 20 ms).
//! - An argument without a literal is resolved once: a bare name bound by `let name = …` earlier
//!   in the same file costs that statement's literals; a bare name that is a `Duration` parameter
//!   of the enclosing function makes that function a sleep helper, and every call of it costs the
//!   literals of that argument; a call of a function without arguments (`soak()`) costs the
//!   literals of that function's body.
//! - What still has no literal (a sleep to a computed deadline) counts 0 and is listed by file
//!   and line, so a reader sees it.
//! - Tests on tokio's paused clock (`#[tokio::test(start_paused = true)]`) are not counted: their
//!   sleeps advance a clock and cost nothing.
//! - Comment lines are skipped; this file is not read.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};

/// Issue 39's bar, reached (98.4 s, from 357 s): the count never goes back above it.
const GOAL_MS: u64 = 100_000;
/// Where the count stands (98.4 s when this was written, from 518 s and then 357 s): it may
/// only go down.
const RATCHET_MS: u64 = 99_000;
// The ratchet holds the goal: a count under the ratchet is under issue 39's bar.
const _: () = assert!(RATCHET_MS <= GOAL_MS, "the ratchet is past issue 39's bar");

fn rust_files(dir: &Path, out: &mut Vec<PathBuf>) {
    for entry in std::fs::read_dir(dir).expect("readable tests") {
        let path = entry.expect("entry").path();
        if path.is_dir() {
            rust_files(&path, out);
        } else if path.extension().is_some_and(|x| x == "rs") && !path.ends_with("sleeps.rs") {
            out.push(path);
        }
    }
}

/// A function's name, first and last line (0-based), parameters and whether it runs on paused time.
struct Function {
    name: String,
    first: usize,
    last: usize,
    params: Vec<String>,
    paused: bool,
}

/// The text of a source file with comment lines blanked (line numbers kept).
fn code_lines(text: &str) -> Vec<String> {
    text.lines()
        .map(|l| {
            if l.trim_start().starts_with("//") {
                String::new()
            } else {
                l.to_string()
            }
        })
        .collect()
}

/// The name after `fn ` on a line that starts a function item, if it does.
fn fn_name(line: &str) -> Option<&str> {
    let mut rest = line.trim_start();
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
    let rest = rest.strip_prefix("fn ")?;
    let end = rest.find(|c: char| !(c.is_alphanumeric() || c == '_'))?;
    Some(&rest[..end])
}

/// Every function of a rustfmt-formatted file: from its `fn` line to the first line that closes a
/// brace at its indentation.
fn functions(lines: &[String]) -> Vec<Function> {
    let mut found = Vec::new();
    for (i, line) in lines.iter().enumerate() {
        let Some(name) = fn_name(line) else { continue };
        let indent = &line[..line.len() - line.trim_start().len()];
        let close = format!("{indent}}}");
        let Some(end) = lines[i..].iter().position(|l| l.starts_with(&close)) else {
            continue;
        };
        let signature: String = lines[i..=i + end].join(" ");
        let open = signature.find("fn ").unwrap_or(0);
        let open = open + signature[open..].find('(').unwrap_or(0);
        let params = balanced(&signature[open..])
            .map(|p| split_args(&p))
            .unwrap_or_default();
        let mut paused = false;
        for attr in lines[..i].iter().rev() {
            let attr = attr.trim();
            if !attr.starts_with("#[") {
                break;
            }
            paused |= attr.contains("start_paused = true");
        }
        found.push(Function {
            name: name.to_string(),
            first: i,
            last: i + end,
            params,
            paused,
        });
    }
    found
}

/// The text inside the parentheses that open at the start of `s`.
fn balanced(s: &str) -> Option<String> {
    let mut depth = 0;
    for (i, c) in s.char_indices() {
        match c {
            '(' => depth += 1,
            ')' => {
                depth -= 1;
                if depth == 0 {
                    return Some(s[1..i].to_string());
                }
            }
            _ => {}
        }
    }
    None
}

/// Arguments (or parameters) split at commas outside brackets.
fn split_args(s: &str) -> Vec<String> {
    let (mut out, mut depth, mut current) = (Vec::new(), 0, String::new());
    for c in s.chars() {
        match c {
            '(' | '[' | '{' | '<' => depth += 1,
            ')' | ']' | '}' | '>' => depth -= 1,
            ',' if depth == 0 => {
                out.push(current.trim().to_string());
                current.clear();
                continue;
            }
            _ => {}
        }
        current.push(c);
    }
    if !current.trim().is_empty() {
        out.push(current.trim().to_string());
    }
    out
}

/// The sum, in milliseconds, of the duration literals in `s`, if it has any.
fn literal_ms(s: &str) -> Option<u64> {
    let mut total = None;
    for (call, per_unit) in [
        ("from_secs(", 1000.0),
        ("from_millis(", 1.0),
        ("from_micros(", 0.001),
        ("from_secs_f64(", 1000.0),
    ] {
        for (at, _) in s.match_indices(call) {
            let arg = balanced(&s[at + call.len() - 1..]).unwrap_or_default();
            // An expression (`500 + next() % 1500`) costs the sum of its numbers: a bound.
            let number: String = arg.chars().filter(|c| *c != '_').collect();
            let numbers: Vec<f64> = number
                .split(|c: char| !(c.is_ascii_digit() || c == '.'))
                .filter_map(|n| n.parse::<f64>().ok())
                .collect();
            if !numbers.is_empty() && !number.contains(" as ") {
                *total.get_or_insert(0) += (numbers.iter().sum::<f64>() * per_unit).round() as u64;
            }
        }
    }
    total
}

/// A file read for counting.
struct Source {
    name: String,
    lines: Vec<String>,
    functions: Vec<Function>,
}

impl Source {
    fn enclosing(&self, line: usize) -> Option<&Function> {
        self.functions
            .iter()
            .filter(|f| f.first <= line && line <= f.last)
            .min_by_key(|f| f.last - f.first)
    }

    /// The statement that starts at `line`, up to its `;`.
    fn statement(&self, line: usize) -> String {
        let mut s = String::new();
        for l in &self.lines[line..] {
            s.push_str(l);
            if l.trim_end().ends_with(';') {
                break;
            }
        }
        s
    }
}

/// One counted sleep: where, and what it costs (`None`: no literal found).
struct Sleep {
    file: String,
    line: usize,
    ms: Option<u64>,
}

/// The cost of an argument `arg` of a sleep (or of a helper's call) at `line` of `src`.
fn resolve(sources: &[Source], src: &Source, line: usize, arg: &str) -> Option<u64> {
    if let Some(ms) = literal_ms(arg) {
        return Some(ms);
    }
    let name: String = arg
        .trim()
        .chars()
        .take_while(|c| c.is_alphanumeric() || *c == '_')
        .collect();
    if name.is_empty() {
        return None;
    }
    let rest = arg.trim()[name.len()..].trim_start();
    if rest.starts_with("()") {
        let f = sources
            .iter()
            .flat_map(|s| s.functions.iter().map(move |f| (s, f)))
            .find(|(_, f)| f.name == name)?;
        return literal_ms(&f.0.lines[f.1.first..=f.1.last].join(" "));
    }
    let binding = format!("let {name} = ");
    let bound = (0..line)
        .rev()
        .find(|&i| src.lines[i].contains(&binding))
        .filter(|&i| src.enclosing(i).map(|f| f.first) == src.enclosing(line).map(|f| f.first));
    bound.and_then(|i| literal_ms(&src.statement(i)))
}

/// The name a sleep's argument may take from its function's parameters (`settle`, or `secs` in
/// `Duration::from_secs(secs)`), and the milliseconds of one unit of a number passed for it
/// (`None`: a `Duration` is passed).
fn parameter(arg: &str) -> (String, Option<u64>) {
    let arg = arg.trim();
    for (call, unit) in [
        ("Duration::from_secs(", 1000),
        ("Duration::from_millis(", 1),
    ] {
        if let Some(inner) = arg.strip_prefix(call).and_then(|a| a.strip_suffix(')')) {
            return (inner.trim().to_string(), Some(unit));
        }
    }
    (arg.to_string(), None)
}

/// The calls of `name` in every source, and the cost of their argument at `index` (a duration,
/// or a number of `unit` milliseconds).
fn helper_calls(
    sources: &[Source],
    name: &str,
    index: usize,
    unit: Option<u64>,
    out: &mut Vec<Sleep>,
) {
    let call = format!("{name}(");
    for src in sources {
        let text = src.lines.join("\n");
        for (at, _) in text.match_indices(&call) {
            let before = text[..at].chars().last().unwrap_or(' ');
            let line = text[..at].matches('\n').count();
            if before.is_alphanumeric() || before == '_' || fn_name(&src.lines[line]).is_some() {
                continue;
            }
            if src.enclosing(line).is_some_and(|f| f.paused) {
                continue;
            }
            let args = balanced(&text[at + name.len()..])
                .map(|a| split_args(&a))
                .unwrap_or_default();
            let arg = args.get(index).cloned().unwrap_or_default();
            let number = arg.replace('_', "").parse::<u64>().ok();
            let ms = match unit {
                Some(unit) => number.map(|n| n * unit),
                None => resolve(sources, src, line, &arg),
            };
            out.push(Sleep {
                file: src.name.clone(),
                line: line + 1,
                ms,
            });
        }
    }
}

/// Every sleep of every source outside tests on paused time.
fn sleeps(sources: &[Source]) -> Vec<Sleep> {
    let mut out = Vec::new();
    for src in sources {
        for (i, line) in src.lines.iter().enumerate() {
            for call in ["sleep(", "sleep_until("] {
                for (at, _) in line.match_indices(call) {
                    let before = line[..at].chars().last().unwrap_or(' ');
                    if before.is_alphanumeric() || (before == '_' && !line[..at].ends_with("::")) {
                        continue;
                    }
                    let function = src.enclosing(i);
                    if function.is_some_and(|f| f.paused) {
                        continue;
                    }
                    let rest = src.lines[i..].join(" ");
                    let arg = balanced(&rest[at + call.len() - 1..]).unwrap_or_default();
                    let (name, unit) = parameter(&arg);
                    let param = function.and_then(|f| {
                        f.params
                            .iter()
                            .position(|p| p.starts_with(&format!("{name}:")))
                            .map(|index| (f.name.clone(), index))
                    });
                    match param {
                        Some((helper, index)) => {
                            helper_calls(sources, &helper, index, unit, &mut out)
                        }
                        None => out.push(Sleep {
                            file: src.name.clone(),
                            line: i + 1,
                            ms: resolve(sources, src, i, &arg),
                        }),
                    }
                }
            }
        }
    }
    out
}

fn sources() -> Vec<Source> {
    let root = Path::new(env!("CARGO_MANIFEST_DIR"));
    let mut files = Vec::new();
    rust_files(&root.join("tests"), &mut files);
    files.sort();
    files
        .iter()
        .map(|path| {
            let lines = code_lines(&std::fs::read_to_string(path).expect("readable"));
            Source {
                name: path.strip_prefix(root).unwrap().display().to_string(),
                functions: functions(&lines),
                lines,
            }
        })
        .collect()
}

#[test]
fn literal_sleeps_in_the_tests_never_grow_past_the_ratchet() {
    let sleeps = sleeps(&sources());
    let mut per_file: BTreeMap<&str, u64> = BTreeMap::new();
    for s in &sleeps {
        *per_file.entry(&s.file).or_default() += s.ms.unwrap_or(0);
    }
    let total: u64 = per_file.values().sum();
    for (file, ms) in &per_file {
        println!("{:>9.3} s  {file}", *ms as f64 / 1000.0);
    }
    for s in sleeps.iter().filter(|s| s.ms.is_none()) {
        println!("no literal (counted 0): {}:{}", s.file, s.line);
    }
    println!(
        "{:>9.3} s  in all (the goal: {} s; the ratchet: {} s)",
        total as f64 / 1000.0,
        GOAL_MS / 1000,
        RATCHET_MS / 1000
    );
    assert!(
        total <= RATCHET_MS,
        "{:.3} s of literal sleeps in tests/ (the ratchet: {} s, the goal {} s): wait for a condition, or move the test to paused time",
        total as f64 / 1000.0,
        RATCHET_MS / 1000,
        GOAL_MS / 1000
    );
}

#[test]
fn a_sleep_is_counted_by_its_literals_once_and_paused_tests_are_not() {
    let text = r#"
async fn helper(settle: Duration) {
    tokio::time::sleep(settle).await;
}

#[tokio::test]
async fn real() {
    let window = Duration::from_secs(3);
    tokio::time::sleep(window).await;
    for _ in 0..10 {
        std::thread::sleep(Duration::from_millis(20));
    }
    helper(Duration::from_millis(1500)).await;
}

#[tokio::test(start_paused = true)]
async fn paused() {
    tokio::time::sleep(Duration::from_secs(60)).await;
    helper(Duration::from_secs(60)).await;
}
"#;
    let lines = code_lines(text);
    let src = Source {
        name: "t.rs".into(),
        functions: functions(&lines),
        lines,
    };
    let found = sleeps(std::slice::from_ref(&src));
    let ms: Vec<Option<u64>> = found.iter().map(|s| s.ms).collect();
    assert_eq!(ms, [Some(1500), Some(3000), Some(20)]);
}

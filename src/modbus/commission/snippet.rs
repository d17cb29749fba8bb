//! A ready-to-paste gateway config for what a scan found. Pure.

use std::collections::BTreeMap;
use std::fmt::Write as _;

use crate::commission::target::Target;
use crate::config::Parity;
use crate::outcome::Found;

/// A whole config file (gateway, MQTT, one bus) for the modules in `found`. The bus runs at the
/// baud rate most of them answered at; a module at another rate gets its own `baud`.
pub fn config_snippet(target: &Target, found: &[Found]) -> String {
    let mut t = String::from(
        "# Written by `pulsegate scan --toml`. Check it with `pulsegate check --config FILE`.\n\
         [gateway]\n# id = \"<host name>\"\nstate_dir = \"/var/lib/pulsegate\"\n\n\
         [mqtt]\nhost = \"127.0.0.1\"\nport = 1883\n\n",
    );
    let known: Vec<&Found> = found.iter().filter(|f| f.model.is_some()).collect();
    if known.is_empty() {
        // A bus needs a device: without one the file would not pass `check`.
        t += "# No module of a known model answered, so there is no bus here yet.\n";
    }
    let line_baud = most_common_baud(&known);
    match target {
        _ if known.is_empty() => {}
        Target::Serial { port, parity } => {
            let _ = writeln!(t, "[buses.line1]\nport = {:?}", port.display().to_string());
            let _ = writeln!(t, "baud = {}", line_baud.unwrap_or(9600));
            if *parity != Parity::None {
                let p = if *parity == Parity::Even {
                    "even"
                } else {
                    "odd"
                };
                let _ = writeln!(t, "parity = \"{p}\"");
            }
        }
        Target::Tcp { host, port } => {
            let _ = writeln!(t, "[buses.line1]\nhost = {host:?}\nport = {port}");
        }
    }
    let mut names: BTreeMap<String, usize> = BTreeMap::new();
    for f in &known {
        let model = f.model.as_deref().unwrap_or_default();
        let base = format!("{model}-{}", f.unit);
        let n = names.entry(base.clone()).or_default();
        *n += 1;
        let name = match (*n, f.baud) {
            (1, _) => base,
            (_, Some(b)) => format!("{base}-{b}"),
            (k, None) => format!("{base}-{k}"),
        };
        let _ = writeln!(t, "\n[buses.line1.devices.{name}]\nunit = {}", f.unit);
        let _ = writeln!(t, "model = {model:?}");
        if f.baud.is_some() && f.baud != line_baud {
            let _ = writeln!(
                t,
                "baud = {}   # answers at another rate than the line; \
                 `pulsegate setup --new-baud` can move it",
                f.baud.unwrap_or_default()
            );
        }
        let _ = writeln!(t, "poll = \"1s\"");
        if !f.channels.is_empty() {
            let _ = writeln!(t, "# work modes {:?}: {}", f.modes, f.channels.join(" "));
        }
    }
    for f in found.iter().filter(|f| f.model.is_none()) {
        let at = f.baud.map(|b| format!(" at {b} baud")).unwrap_or_default();
        let _ = writeln!(
            t,
            "\n# unit {}{at}: {}",
            f.unit,
            f.note.as_deref().unwrap_or("unknown model")
        );
    }
    t
}

/// The rate most modules answered at; on a tie the faster one.
fn most_common_baud(found: &[&Found]) -> Option<u32> {
    let mut count: BTreeMap<u32, usize> = BTreeMap::new();
    for f in found {
        if let Some(b) = f.baud {
            *count.entry(b).or_default() += 1;
        }
    }
    count
        .into_iter()
        .max_by(|a, b| a.1.cmp(&b.1).then(a.0.cmp(&b.0)))
        .map(|(b, _)| b)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn found(baud: u32, unit: u8, model: Option<&str>) -> Found {
        Found {
            baud: Some(baud),
            unit,
            model: model.map(str::to_string),
            modes: vec![0],
            channels: vec!["enc0".into()],
            note: model.is_none().then(|| "unknown model".into()),
            meter: None,
        }
    }

    #[test]
    fn the_line_runs_at_the_common_rate_and_others_keep_theirs() {
        let target = Target::Serial {
            port: "/dev/ttyUSB0".into(),
            parity: Parity::None,
        };
        let t = config_snippet(
            &target,
            &[
                found(9600, 1, Some("yl67")),
                found(9600, 3, Some("zh-yx1600")),
                found(19200, 5, Some("wj157")),
                found(9600, 9, None),
            ],
        );
        assert!(t.contains("baud = 9600\n"), "{t}");
        assert!(
            t.contains("[buses.line1.devices.wj157-5]\nunit = 5\nmodel = \"wj157\"\nbaud = 19200")
        );
        assert!(t.contains("# unit 9 at 9600 baud: unknown model"));
        let v: toml::Value = toml::from_str(&t).unwrap();
        assert_eq!(v["buses"]["line1"]["devices"].as_table().unwrap().len(), 3);
    }
}

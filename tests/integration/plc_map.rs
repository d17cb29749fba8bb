//! The register map is a contract with PLC programs: `pulsegate check --register-map --json`
//! prints the same map at every run, and a device appended to the config moves nothing that
//! was in it. No module needs to be on the line for it.

use std::process::Command;

use serde_json::Value;

use crate::plc::register_map;
use crate::support::*;

/// A YL67, a ZH-YX1600 with a unit id and a block of its own choosing, and an M-Bus meter
/// whose channels pick records (and one that picks none).
const PLANT: &str = r#"[gateway]
id = "map"
state_dir = "/nonexistent/pulsegate-map"
[mqtt]
host = "127.0.0.1"
[outputs.json]
kind = "json"
[outputs.plc]
kind = "modbus"
commands = true

[buses.line1]
host = "127.0.0.1"
port = 5020
[buses.line1.devices.press]
unit = 3
model = "yl67"
[buses.line1.devices.pack]
unit = 4
model = "zh-yx1600"
server_unit = 40
channels.di2 = { register = 1000 }

[buses.heat]
protocol = "mbus"
host = "127.0.0.1:10001"
[buses.heat.devices.flat1]
address = 5
channels.energy = { record = 0 }
channels.volume = { record = 2 }
channels.note = {}
"#;

/// One more module on line1 and one more meter on heat, appended.
const APPENDED: &str = r#"
[buses.line1.devices.wrap]
unit = 7
model = "wj157"

[buses.heat.devices.flat2]
address = 6
channels.energy = { record = 0 }
"#;

fn printed(config: &std::path::Path) -> Vec<u8> {
    let out = Command::new(bin())
        .args(["check", "--config"])
        .arg(config)
        .args(["--register-map", "--json"])
        .output()
        .unwrap();
    assert!(out.status.success());
    out.stdout
}

#[test]
fn the_printed_map_is_the_same_at_every_run_and_an_appended_device_moves_nothing() {
    let dir = temp_dir("plc-map");
    let first = dir.join("first.toml");
    let second = dir.join("second.toml");
    std::fs::write(&first, PLANT).unwrap();
    std::fs::write(&second, format!("{PLANT}{APPENDED}")).unwrap();

    let runs: Vec<Vec<u8>> = (0..3).map(|_| printed(&first)).collect();
    assert!(
        runs.windows(2).all(|w| w[0] == w[1]),
        "the same bytes each run"
    );

    let before = register_map(&first);
    let after = register_map(&second);
    let moved: Vec<&Value> = before.iter().filter(|e| !after.contains(e)).collect();
    assert!(moved.is_empty(), "entries changed or gone: {moved:#?}");
    let units = |map: &[Value], device: &str| -> Vec<u64> {
        let mut u: Vec<u64> = map
            .iter()
            .filter(|e| e["device"] == device)
            .map(|e| e["unit_id"].as_u64().unwrap())
            .collect();
        u.dedup();
        u
    };
    assert_eq!(
        units(&after, "wrap"),
        [7],
        "the new module answers as its unit"
    );
    assert_eq!(
        units(&after, "flat2"),
        [6],
        "the new meter as its primary address"
    );
    assert_eq!(units(&after, "pack"), [40]);
    // What the map promises: a channel's block from its place in the model (or its record),
    // pins where pinned.
    let at = |device: &str, channel: &str| -> u64 {
        before
            .iter()
            .find(|e| e["device"] == device && e["channel"] == channel && e["field"] == "total")
            .unwrap()["address"]
            .as_u64()
            .unwrap()
    };
    assert_eq!(at("press", "enc0"), 20);
    assert_eq!(at("pack", "di2"), 1000);
    assert_eq!(at("flat1", "energy"), 20);
    assert_eq!(at("flat1", "volume"), 60, "record 2: block 3");
    assert_eq!(at("flat1", "note"), 80, "after the highest record");
}

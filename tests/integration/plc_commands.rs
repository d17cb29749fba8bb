//! Writes to the Modbus server output's command registers, from pymodbus, mbpoll and
//! tokio-modbus: refused with `commands` off (exception 01, nothing written to the module), and
//! executed with it on, as the module's own count, the MQTT readings and the device block's
//! `result` show.

use std::time::Duration;

use serde_json::json;
use tokio_modbus::client::Writer as _;

use crate::plc::*;
use crate::support::*;

/// The registers of `a1` (count 777, still) in the map: its block's first address.
fn a1_block(rig: &Rig) -> u16 {
    rig.address("m", Some("a1"), "total")
}

fn module_count(rig: &Rig, channel: &str) -> i64 {
    rig.plant
        .with_module("line1", 3, |m, now| m.channel(channel).unwrap().count(now))
        .unwrap()
}

/// The last published readings of `a1` that carry `event`.
fn readings_with(rig: &Rig, event: &str) -> Vec<serde_json::Value> {
    readings(&rig.sub, "pulsegate/test/m/a1")
        .into_iter()
        .filter(|r| r["event"] == event)
        .collect()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn writes_with_commands_off_are_refused_with_exception_01_and_change_nothing() {
    let rig = Rig::start("plc-writes-off", Setup::default()).await;
    let base = a1_block(&rig);
    let (clear, preset) = (base + 12, base + 13);
    let mut py = Pymodbus::connect(rig.port, None);
    let a = py.ask(json!({"op": "write", "unit": 3, "address": clear, "value": 1}));
    assert_eq!(a["exception"], 1, "pymodbus clear: {a}");
    let a = py.ask(
        json!({"op": "write_registers", "unit": 3, "address": preset, "values": [0, 0, 0, 5]}),
    );
    assert_eq!(a["exception"], 1, "pymodbus preset: {a}");
    let e = mbpoll_write(rig.port, 3, clear, &[1]).unwrap_err();
    assert!(e.contains("Illegal function"), "mbpoll: {e}");
    let mut ctx = tokio_modbus::client::tcp::connect_slave(rig.addr(), tokio_modbus::Slave(3))
        .await
        .unwrap();
    let r = ctx.write_single_register(clear, 1).await.unwrap();
    assert_eq!(r, Err(tokio_modbus::ExceptionCode::IllegalFunction));

    // Polls go on; nothing reached the module or changed.
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert_eq!(
        rig.plant.with_module("line1", 3, |m, _| m.writes).unwrap(),
        0
    );
    assert_eq!(module_count(&rig, "a1"), 777);
    assert!(readings_with(&rig, "cleared").is_empty());
    assert!(readings_with(&rig, "preset").is_empty());
    let head = py.read(3, 0, 5).unwrap();
    assert_eq!(head[3..], [0, 0], "no result, no command channel: {head:?}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_clear_and_a_preset_written_with_commands_on_are_executed() {
    let setup = Setup {
        server: "commands = true\n",
        ..Setup::default()
    };
    let rig = Rig::start("plc-writes-on", setup).await;
    let base = a1_block(&rig);
    let (clear, preset) = (base + 12, base + 13);
    let total_before = rig.last_total("m", "a1").await;
    let mut py = Pymodbus::connect(rig.port, None);

    // Clear (pymodbus, function 06): answered once done.
    let a = py.ask(json!({"op": "write", "unit": 3, "address": clear, "value": 1}));
    assert_eq!(a, json!({"ok": true}), "{}", rig.gw.log_text());
    assert_eq!(module_count(&rig, "a1"), 0, "the module's count cleared");
    assert_eq!(
        py.read(3, 3, 2).unwrap(),
        [2, base],
        "result done, on a1's block"
    );
    let cleared = rig
        .sub
        .wait_for("pulsegate/test/m/a1", Duration::from_secs(5), |m| {
            m.json()["event"] == "cleared"
        })
        .await
        .expect("a reading says cleared")
        .json();
    assert_eq!(cleared["count"], 0, "{cleared}");
    assert_eq!(
        cleared["total"], total_before,
        "a clear never moves the total"
    );

    // Preset 123456 (mbpoll, four registers high word first: function 16).
    let v = 123_456i64;
    let words = [0, 0, v >> 16, v & 0xFFFF];
    mbpoll_write(rig.port, 3, preset, &words).unwrap();
    assert_eq!(module_count(&rig, "a1"), v);
    assert_eq!(py.read(3, 3, 2).unwrap(), [2, base]);
    assert!(
        rig.sub
            .wait_for("pulsegate/test/m/a1", Duration::from_secs(5), |m| m.json()
                ["event"]
                == "preset"
                && m.json()["count"] == v)
            .await
            .is_some()
    );

    // A preset out of the channel's range (a u32 input): refused, result 3, nothing written.
    let writes = rig.plant.with_module("line1", 3, |m, _| m.writes).unwrap();
    let minus_five = [0xFFFF, 0xFFFF, 0xFFFF, 0xFFFB];
    let a = py
        .ask(json!({"op": "write_registers", "unit": 3, "address": preset, "values": minus_five}));
    assert_eq!(a["exception"], 4, "{a}");
    assert_eq!(py.read(3, 3, 2).unwrap(), [3, base], "result refused");
    assert_eq!(
        rig.plant.with_module("line1", 3, |m, _| m.writes).unwrap(),
        writes
    );
    assert_eq!(module_count(&rig, "a1"), v);

    // Not a command: clear with 2 (03), a total (02), a preset in one register (03).
    let a = py.ask(json!({"op": "write", "unit": 3, "address": clear, "value": 2}));
    assert_eq!(a["exception"], 3, "{a}");
    let a = py.ask(json!({"op": "write", "unit": 3, "address": base, "value": 1}));
    assert_eq!(a["exception"], 2, "{a}");
    let a = py.ask(json!({"op": "write", "unit": 3, "address": preset, "value": 1}));
    assert_eq!(a["exception"], 3, "{a}");
    assert_eq!(
        rig.plant.with_module("line1", 3, |m, _| m.writes).unwrap(),
        writes
    );
}

/// `commands = true` written into the config and a SIGHUP: the output is rebuilt on the same
/// port, and a clear that was refused before is executed.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn commands_turned_on_by_a_reload_take_effect_on_the_same_port() {
    let rig = Rig::start("plc-reload", Setup::default()).await;
    let clear = a1_block(&rig) + 12;
    let mut py = Pymodbus::connect(rig.port, None);
    let a = py.ask(json!({"op": "write", "unit": 3, "address": clear, "value": 1}));
    assert_eq!(a["exception"], 1, "{a}");
    let text = std::fs::read_to_string(&rig.config).unwrap();
    let on = text.replace(
        "kind = \"modbus\"\n",
        "kind = \"modbus\"\ncommands = true\n",
    );
    assert_ne!(text, on);
    std::fs::write(&rig.config, on).unwrap();
    rig.gw.signal("HUP");
    let deadline = std::time::Instant::now() + Duration::from_secs(10);
    let answer = loop {
        // The rebuilt output closed the connections of the old one: a new one each time.
        let mut py = Pymodbus::connect(rig.port, None);
        let a = py.ask(json!({"op": "write", "unit": 3, "address": clear, "value": 1}));
        if a["ok"] == true || std::time::Instant::now() > deadline {
            break a;
        }
        tokio::time::sleep(Duration::from_millis(200)).await;
    };
    assert_eq!(answer, json!({"ok": true}), "{}", rig.gw.log_text());
    assert_eq!(module_count(&rig, "a1"), 0);
    assert!(!rig.gw.log_text().contains("cannot listen"));
}

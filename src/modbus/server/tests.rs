//! The Modbus server output's map, image and answers, without a socket.

use std::path::Path;
use std::time::{Duration, SystemTime};

use tokio_modbus::{ExceptionCode, Request, Response};

use super::answer::{Asked, Op, answer};
use super::image::Image;
use crate::config::Config;
use crate::modbus::config::server::map::{BLOCK, RegisterMap, result};
use crate::reading::{Output, Reading};

const DEVICES: &str = "[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.press]\nunit = 3\nmodel = \"yl67\"\n";

fn config(extra: &str) -> Config {
    let text = format!(
        "[gateway]\nid = \"e1\"\n{DEVICES}{extra}[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\n"
    );
    Config::from_toml(&text, Path::new("x.toml"), Some(Default::default())).unwrap()
}

fn errors(extra: &str) -> String {
    let text = format!(
        "[gateway]\nid = \"e1\"\n{DEVICES}{extra}[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\n"
    );
    Config::from_toml(&text, Path::new("x.toml"), Some(Default::default()))
        .unwrap_err()
        .to_string()
}

fn reading(channel: &str, total: i64, seq: u64) -> Reading {
    let mut r = Reading::sample("press", channel, seq);
    r.update.total = total;
    r.ts = SystemTime::UNIX_EPOCH + Duration::from_secs(1000);
    r
}

fn words_i64(w: &[u16]) -> i64 {
    w.iter().fold(0i64, |acc, x| (acc << 16) | i64::from(*x))
}

#[test]
fn a_module_answers_as_its_own_unit_with_a_block_per_channel_of_its_model() {
    let map = RegisterMap::of(&config(""));
    let d = &map.units[&3];
    assert_eq!(d.device, "press");
    // YL67: enc0, a0, b0, enc1, … in its profile's order, whatever its work modes.
    assert_eq!(d.channels["enc0"], BLOCK);
    assert_eq!(d.channels["a0"], 2 * BLOCK);
    assert_eq!(d.channels.len(), 12, "{:?}", d.channels);
}

#[test]
fn an_appended_device_moves_nothing_that_was_there() {
    let before = RegisterMap::of(&config("")).entries(true);
    let more = "[buses.l.devices.aaa]\nunit = 7\nmodel = \"wj157\"\n";
    let after = RegisterMap::of(&config(more)).entries(true);
    for e in &before {
        assert!(after.contains(e), "{e:?} moved");
    }
    assert!(after.len() > before.len());
}

#[test]
fn a_pinned_block_stays_and_collisions_are_refused() {
    let pinned = "[buses.l.devices.press.channels.a0]\nregister = 1000\n";
    assert_eq!(
        RegisterMap::of(&config(pinned)).units[&3].channels["a0"],
        1000
    );
    let overlap = "[buses.l.devices.press.channels.a0]\nregister = 25\n";
    assert!(errors(overlap).contains("overlaps"), "{}", errors(overlap));
    let twice = "[buses.l2]\nhost = \"127.0.0.2\"\nport = 502\n[buses.l2.devices.other]\nunit = 3\nmodel = \"yl67\"\n";
    let e = errors(twice);
    assert!(e.contains("server_unit") && e.contains("press"), "{e}");
    let moved = format!("{twice}server_unit = 4\n");
    let map = RegisterMap::of(&config(&moved));
    assert_eq!(map.units[&4].device, "other");
}

#[test]
fn a_poll_replaces_a_devices_words_whole_and_reads_never_tear() {
    let map = RegisterMap::of(&config(""));
    let mut image = Image::new(&map);
    let a0 = map.units[&3].channels["a0"];
    let now = SystemTime::UNIX_EPOCH + Duration::from_secs(1005);
    let head = image.units[&3].read(0, 3, now).unwrap();
    assert_eq!(head, [0, 0xFFFF, 0xFFFF], "offline, never answered");
    let before = image.units[&3].clone();
    let total = 0x0001_0002_0003_0004;
    image.apply(&Output::DeviceReadings {
        device: "press".into(),
        readings: vec![reading("a0", total, 7)],
    });
    assert_eq!(
        words_i64(&before.read(a0, 4, now).unwrap()),
        0,
        "a request that took the words before the poll sees all of before"
    );
    let after = &image.units[&3];
    assert_eq!(words_i64(&after.read(a0, 4, now).unwrap()), total);
    assert_eq!(after.read(a0 + 6, 2, now).unwrap(), [0, 7], "seq");
    assert_eq!(
        after.read(0, 3, now).unwrap(),
        [1, 0, 5],
        "online, 5 s since"
    );
    let value = after.read(a0 + 8, 4, now).unwrap();
    assert!(
        f64::from_bits(words_i64(&value) as u64).is_nan(),
        "no unit: NaN"
    );
    image.apply(&Output::DeviceStatus {
        device: "press".into(),
        online: false,
    });
    let kept = &image.units[&3];
    assert_eq!(kept.read(0, 1, now).unwrap(), [0]);
    assert_eq!(
        words_i64(&kept.read(a0, 4, now).unwrap()),
        total,
        "last value kept"
    );
}

#[test]
fn requests_are_answered_or_refused_as_a_modbus_gateway_does() {
    let map = RegisterMap::of(&config(""));
    let image = Image::new(&map);
    let now = SystemTime::UNIX_EPOCH;
    let ask = |unit, r: Request<'_>, commands| answer(&image, commands, unit, &r, now);
    assert!(matches!(
        ask(3, Request::ReadInputRegisters(0, 125), false),
        Ok(Asked::Answer(Response::ReadInputRegisters(w))) if w.len() == 125
    ));
    assert!(matches!(
        ask(3, Request::ReadHoldingRegisters(20, 4), false),
        Ok(Asked::Answer(Response::ReadHoldingRegisters(_)))
    ));
    let refused = [
        (
            9,
            Request::ReadInputRegisters(0, 1),
            ExceptionCode::GatewayTargetDevice,
        ),
        (
            3,
            Request::ReadInputRegisters(0, 126),
            ExceptionCode::IllegalDataValue,
        ),
        (
            3,
            Request::ReadInputRegisters(0, 0),
            ExceptionCode::IllegalDataValue,
        ),
        (
            3,
            Request::ReadInputRegisters(255, 10),
            ExceptionCode::IllegalDataAddress,
        ),
        (3, Request::ReadCoils(0, 1), ExceptionCode::IllegalFunction),
        (
            3,
            Request::WriteSingleRegister(32, 1),
            ExceptionCode::IllegalFunction,
        ),
    ];
    for (unit, r, e) in refused {
        assert_eq!(ask(unit, r.clone(), false), Err(e), "{r:?}");
    }
}

#[test]
fn with_commands_on_a_clear_or_a_preset_is_a_command_and_nothing_else_is() {
    let map = RegisterMap::of(&config(""));
    let mut image = Image::new(&map);
    let a0 = map.units[&3].channels["a0"];
    let now = SystemTime::UNIX_EPOCH;
    let clear = answer(
        &image,
        true,
        3,
        &Request::WriteSingleRegister(a0 + 12, 1),
        now,
    );
    let Ok(Asked::Command(c)) = clear else {
        panic!("{clear:?}")
    };
    assert_eq!(
        (c.device.as_str(), c.channel.as_str(), c.op, c.base),
        ("press", "a0", Op::Clear, a0)
    );
    let preset = [0, 0, 0, 3000];
    let r = Request::WriteMultipleRegisters(a0 + 13, preset.to_vec().into());
    let Ok(Asked::Command(c)) = answer(&image, true, 3, &r, now) else {
        panic!()
    };
    assert_eq!(c.op, Op::Preset(3000));
    let not_one = Request::WriteSingleRegister(a0 + 12, 2);
    assert_eq!(
        answer(&image, true, 3, &not_one, now),
        Err(ExceptionCode::IllegalDataValue)
    );
    let total = Request::WriteSingleRegister(a0, 1);
    assert_eq!(
        answer(&image, true, 3, &total, now),
        Err(ExceptionCode::IllegalDataAddress)
    );
    image.command(3, a0, result::DONE);
    assert_eq!(image.units[&3].read(3, 2, now).unwrap(), [result::DONE, a0]);
}

//! The board without a runtime: events in, snapshots out.

use std::path::Path;
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use super::board::{Board, MAX_CHANNELS, Measured};
use crate::config::Config;
use crate::counter::Update;
use crate::event::Event;
use crate::health::{Loop, LoopView};
use crate::reading::{Output, Reading};

const CONFIG: &str = r#"
[gateway]
id = "hall"
state_dir = "/tmp/pulsegate-board-test"
[mqtt]
host = "broker"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.press]
unit = 1
model = "yl67"
intervals = ["15min"]
[buses.line1.devices.press.channels.a0]
scale = 0.01
unit = "<b>kWh</b>"
[buses.line1.devices.spindle]
unit = 2
model = "wj157"
"#;

const T0: u64 = 1_800_000_000_000;

fn config(text: &str) -> Config {
    Config::from_toml(
        text,
        Path::new("/etc/pulsegate/pulsegate.toml"),
        Some(Default::default()),
    )
    .expect("valid config")
}

fn reading(device: &str, channel: &str, at: u64, count: i64, delta: i64, seq: u64) -> Reading {
    let mut r = Reading::sample(device, channel, seq);
    r.ts = SystemTime::UNIX_EPOCH + Duration::from_millis(at);
    r.count = count;
    r.kind = crate::profile::ChannelKind::Counter;
    r.update = Update {
        delta,
        total: count,
        seq,
        rate_hz: Some(10.0),
        event: None,
    };
    r
}

fn status(board: &Board, now: u64) -> super::view::Status {
    board.status(now, &Measured::default())
}

#[test]
fn a_reading_shows_as_published_with_its_units_as_plain_values() {
    let c = config(CONFIG);
    let mut board = Board::new(&c, T0);
    let mut r = reading("press", "a0", T0 + 1000, 1234, 4, 7);
    r.units = Some(Arc::new(c.buses[0].devices[0].channels["a0"].units.clone()));
    board.hand(&Output::single(r), T0 + 1000);
    let s = status(&board, T0 + 2000);
    let press = &s.devices[0];
    assert_eq!(
        (press.name.as_str(), press.bus.as_str(), press.unit),
        ("press", "line1", 1)
    );
    assert_eq!(press.model, "yl67");
    let a0 = &press.channels[0];
    assert_eq!((a0.count, a0.total, a0.delta, a0.seq), (1234, 1234, 4, 7));
    assert_eq!(
        a0.unit.as_deref(),
        Some("<b>kWh</b>"),
        "names and units are data, not markup"
    );
    assert_eq!(a0.value.as_deref(), Some("12.34"));
    assert_eq!(a0.at_ms, T0 + 1000);
    assert_eq!(s.gateway.id, "hall");
    assert_eq!(s.gateway.config_hash, c.hash().to_string());
}

#[test]
fn a_device_going_offline_is_its_status_and_an_event_once() {
    let mut board = Board::new(&config(CONFIG), T0);
    assert_eq!(status(&board, T0).devices[1].status, "unknown");
    let online = Output::DeviceStatus {
        device: "spindle".into(),
        online: true,
    };
    let offline = Output::DeviceStatus {
        device: "spindle".into(),
        online: false,
    };
    board.hand(&online, T0 + 1);
    board.hand(&offline, T0 + 2);
    board.hand(&offline, T0 + 3);
    let s = status(&board, T0 + 5);
    assert_eq!(s.devices[1].status, "offline");
    assert_eq!(s.devices[1].status_since_ms, Some(T0 + 2));
    assert_eq!(s.events.len(), 2, "{:?}", s.events);
    assert!(s.events[0].text.starts_with("offline"), "newest first");
    let problem = Output::DeviceProblem {
        device: "spindle".into(),
        status: "wrong_model",
    };
    board.hand(&problem, T0 + 6);
    assert_eq!(status(&board, T0 + 7).devices[1].status, "wrong_model");
}

#[test]
fn events_of_devices_not_configured_are_left_out() {
    let mut board = Board::new(&config(CONFIG), T0);
    board.hand(&Output::single(reading("ghost", "a0", T0, 1, 1, 1)), T0);
    board.hand(
        &Output::DeviceStatus {
            device: "ghost".into(),
            online: true,
        },
        T0,
    );
    let s = status(&board, T0);
    assert!(s.devices.iter().all(|d| d.name != "ghost"));
    assert!(s.events.is_empty());
}

#[test]
fn channels_per_device_and_events_are_bounded() {
    let mut board = Board::new(&config(CONFIG), T0);
    for i in 0..(MAX_CHANNELS + 20) {
        let r = reading("spindle", &format!("c{i}"), T0 + i as u64, 1, 1, 1);
        board.hand(&Output::single(r), T0);
    }
    for i in 0..150 {
        let mut r = reading("press", "a0", T0 + i, 1, 1, i);
        r.update.event = Some(Event::Reset);
        board.hand(&Output::single(r), T0);
    }
    let s = status(&board, T0 + 100);
    assert_eq!(s.devices[1].channels.len(), MAX_CHANNELS);
    assert_eq!(s.events.len(), super::log::KEPT);
    assert!(s.events[0].text.starts_with("reset"));
}

#[test]
fn the_interval_in_progress_sums_its_readings_and_starts_over_at_the_boundary() {
    let mut board = Board::new(&config(CONFIG), T0);
    let period = 15 * 60 * 1000;
    let start = T0 / period * period;
    board.hand(
        &Output::single(reading("press", "a0", start + 1000, 10, 10, 1)),
        0,
    );
    board.hand(
        &Output::single(reading("press", "a0", start + 2000, 15, 5, 2)),
        0,
    );
    let i = &status(&board, start + 3000).devices[0].channels[0].intervals[0];
    assert_eq!(
        (i.period.as_str(), i.start_ms, i.delta),
        ("15min", start as i64, 15)
    );
    assert_eq!(i.end_ms, (start + period) as i64);
    board.hand(
        &Output::single(reading("press", "a0", start + period + 5, 18, 3, 3)),
        0,
    );
    let i = &status(&board, start + period + 10).devices[0].channels[0].intervals[0];
    assert_eq!((i.start_ms, i.delta), ((start + period) as i64, 3));
}

#[test]
fn the_rate_chart_holds_fifteen_minutes_of_buckets() {
    let mut board = Board::new(&config(CONFIG), T0);
    for s in 0..120 {
        let r = reading("press", "a0", T0 + s * 1000, s as i64 * 20, 20, s + 1);
        board.hand(&Output::single(r), 0);
    }
    let h = &status(&board, T0 + 120_000).devices[0].channels[0].history;
    assert_eq!(h.bucket_s, 30);
    assert_eq!(h.rates.len(), 30);
    let known: Vec<f64> = h.rates.iter().flatten().copied().collect();
    assert!(known.len() >= 4 && known.len() <= 6, "{known:?}");
    assert!((known[1] - 20.0).abs() < 1e-9, "{known:?}");
}

#[test]
fn a_reload_keeps_what_stays_and_forgets_what_went() {
    let mut board = Board::new(&config(CONFIG), T0);
    board.hand(&Output::single(reading("press", "a0", T0, 5, 5, 1)), T0);
    board.hand(&Output::single(reading("spindle", "enc0", T0, 5, 5, 1)), T0);
    let without_spindle = CONFIG.replace(
        "[buses.line1.devices.spindle]\nunit = 2\nmodel = \"wj157\"\n",
        "",
    );
    let c = config(&without_spindle);
    board.reconfigure(&c);
    let s = status(&board, T0);
    assert_eq!(s.devices.len(), 1);
    assert_eq!(
        s.devices[0].channels[0].count, 5,
        "the press kept its reading"
    );
    assert_eq!(s.gateway.config_hash, c.hash().to_string());
}

#[test]
fn outputs_show_their_connection_spool_and_last_error() {
    let board = Board::new(&config(CONFIG), T0);
    let measured = Measured {
        uptime_s: 42,
        loops: vec![LoopView {
            of: Loop::Output("json".into()),
            up: false,
            held: None,
            problem: None,
            last_error: Some(("connection refused".into(), T0 - 5)),
            down_for_ms: Some(3000),
            spool_messages: 12,
            spool_bytes: 2048,
        }],
        ..Measured::default()
    };
    let s = board.status(T0, &measured);
    assert_eq!(s.gateway.uptime_s, 42);
    let o = &s.outputs[0];
    assert_eq!(o.name, "json");
    assert!(!o.connected && o.spooling);
    assert_eq!(o.down_s, Some(3.0));
    assert_eq!(o.last_error.as_deref(), Some("connection refused"));
    assert_eq!(o.broker, "broker:1883");
    assert!(o.spool_limit_bytes > 0);
}

#[test]
fn a_scan_shows_its_progress_then_its_report() {
    use crate::outcome::{Found, Outcome, ScanOutcome, ScanProgress, ScanReport};
    let mut board = Board::new(&config(CONFIG), T0);
    let found = Found {
        baud: Some(9600),
        unit: 5,
        model: Some("yl67".into()),
        modes: vec![],
        channels: vec!["enc0".into()],
        note: None,
        meter: None,
    };
    let progress = ScanProgress {
        bus: "line1".into(),
        id: Some("s1".into()),
        found: found.clone(),
        asked: 10,
        pending: 20,
        elapsed_ms: 900,
    };
    board.hand(
        &Output::ScanProgress {
            topic: "t".into(),
            progress: Box::new(progress),
        },
        T0,
    );
    let scan = status(&board, T0).scan.unwrap();
    assert!(scan.running);
    assert_eq!((scan.asked, scan.pending, scan.found.len()), (10, 20, 1));
    let report = Outcome::Scan(ScanOutcome::Report(ScanReport {
        bus: "line1".into(),
        found: vec![found],
        configured: vec![1, 2],
        asked: 30,
        complete: true,
        elapsed_ms: 2500,
        id: Some("s1".into()),
    }));
    let reply = crate::command::Reply {
        topics: vec![],
        correlation: None,
        via: None,
    };
    board.hand(
        &Output::CommandResult {
            reply,
            outcome: report,
        },
        T0 + 1,
    );
    let s = status(&board, T0 + 2);
    assert!(!s.scan.as_ref().unwrap().running);
    assert!(
        s.events[0].text.contains("1 module(s) found"),
        "{:?}",
        s.events[0]
    );
    assert!(
        status(&board, T0 + 3_600_000).scan.is_none(),
        "an old report leaves the board"
    );
}

#[test]
fn a_meters_gauge_shows_its_value_and_unit_and_the_meter_its_address() {
    let text = r#"
[gateway]
id = "hall"
[buses.mb]
protocol = "mbus"
host = "10.0.0.5:10001"
[buses.mb.devices.water]
address = 5
[buses.mb.devices.heat]
id = "12345678"
"#;
    let mut board = Board::new(&config(text), T0);
    let mut r = reading("heat", "flow_temperature", T0 + 1000, 0, 0, 1);
    r.units = Some(Arc::new(crate::config::units::ChannelUnits {
        unit: Some("°C".into()),
        ..Default::default()
    }));
    r.measured = Some(crate::reading::Measure::Exact(
        crate::decimal::Decimal::parse("60.25").unwrap(),
    ));
    board.hand(&Output::single(r), T0 + 1000);
    let s = status(&board, T0 + 2000);
    let by = |n: &str| s.devices.iter().find(|d| d.name == n).unwrap();
    assert_eq!(by("water").address, "primary address 5");
    let heat = by("heat");
    assert_eq!(heat.address, "id 12345678");
    let c = &heat.channels[0];
    assert_eq!(
        (c.kind, c.value.as_deref(), c.unit.as_deref()),
        ("gauge", Some("60.25"), Some("°C")),
        "a gauge is its value, not a total of 0"
    );
    let modbus = Board::new(&config(CONFIG), T0);
    assert_eq!(status(&modbus, T0).devices[0].address, "unit 1");
}

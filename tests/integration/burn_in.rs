//! Burn-in: the long real-time scenarios (a minute of a noisy line, of a broker away). They prove
//! the real thing end to end; their minute each cannot be shortened without weakening them.
//! They live in this module because libtest starts tests in name order: `burn_in::` sorts first,
//! so the minute-long ones start at once, side by side, and the suite's wall time is the longest
//! of them rather than whatever they queued behind.

use std::time::{Duration, Instant};

use crate::faults::a_broker_away_loses_no_reading;
use crate::protocol::Protocol;
use crate::support::*;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_away_for_60s_loses_no_reading_and_keeps_their_order() {
    a_broker_away_loses_no_reading(Protocol::V5, Duration::from_secs(60)).await;
}

/// 2% of the bytes corrupted, both ways, at 9600 baud for 60 s (`PULSEGATE_NOISE_SECS`): CRC
/// errors and undecodable frames are garbled answers, not line faults, and no device goes
/// offline.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_percent_corrupted_bytes_at_9600_baud_take_no_device_offline() {
    let secs: u64 = std::env::var("PULSEGATE_NOISE_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60);
    let broker = Broker::start();
    let plant = plant(
        r#"
[buses.line1]
line = { baud = 9600, turnaround = "2ms", corrupt = 0.02 }
[buses.line1.devices.a]
unit = 1
model = "yl67"
channels.enc0 = { rate = 100.0 }
[buses.line1.devices.b]
unit = 2
model = "wj157"
channels.enc0 = { rate = 50.0 }
[buses.line1.devices.c]
unit = 3
model = "wj157"
modes = [1]
channels.a0 = { rate = 20.0 }
"#,
    )
    .await;
    let dir = temp_dir("hostile-noise");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "yl67", "500ms"),
        ("line1", "b", 2, "wj157", "500ms"),
        ("line1", "c", 3, "wj157", "500ms"),
    ];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "")
        .replace("baud = 115200", "baud = 9600")
        .replace("timeout = \"100ms\"", "timeout = \"200ms\"");
    let gw = Gateway::start(&write_config(&dir, &text));
    for d in ["a", "b", "c"] {
        assert!(
            sub.wait_for(
                &format!("pulsegate/test/{d}/status"),
                Duration::from_secs(20),
                |m| m.payload == "online"
            )
            .await
            .is_some(),
            "{d} online:\n{}",
            gw.log_text()
        );
    }
    tokio::time::sleep(Duration::from_secs(secs)).await;
    let corrupted = plant
        .bus("line1")
        .unwrap()
        .line
        .as_ref()
        .unwrap()
        .counters
        .corrupted
        .load(std::sync::atomic::Ordering::Relaxed);
    let log = gw.log_text();
    let garbled = log.matches("garbled answer").count();
    println!("noise: {corrupted} bytes corrupted in {secs} s; {garbled} garbled-answer log lines");
    assert!(corrupted > 100, "the line was noisy: {corrupted}");
    assert!(
        !sub.all()
            .iter()
            .any(|m| m.topic.ends_with("/status") && m.payload == "offline"),
        "a device went offline:\n{log}"
    );
    assert!(!log.contains("device offline"), "{log}");
    assert!(!log.contains("line fault"), "{log}");
    // Nor does noise fill the journal: a device that stays online writes at most one error line
    // a minute (the rest are counted in that line and in the bus stats).
    let error_lines = log
        .lines()
        .filter(|l| l.contains(" WARN ") && l.contains("pulsegate::bus::availability"))
        .count();
    let bound = 3 * (secs / 60 + 2) as usize;
    println!("noise: {error_lines} error lines from the devices (bound {bound})");
    assert!(error_lines <= bound, "{error_lines} error lines:\n{log}");
    // The line is saturated at 9600 baud (the YL67's poll alone reads 160 registers, and noisy
    // reads are asked again): readings come slower than the 500 ms asked, but they come.
    let counts: Vec<usize> = ["a/enc0", "b/enc0", "c/a0"]
        .iter()
        .map(|d| sub.on(&format!("pulsegate/test/{d}")).len())
        .collect();
    println!("noise: readings per device {counts:?}");
    assert!(counts.iter().all(|&n| n as u64 >= secs / 3), "{counts:?}");
}

/// Seconds of the long fault scenarios (noisy line): 60 by default, so the suite stays short;
/// `PULSEGATE_SOAK_SECS` runs a longer soak (e.g. 600).
fn soak() -> Duration {
    let secs = std::env::var("PULSEGATE_SOAK_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .unwrap_or(60);
    Duration::from_secs(secs)
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_noisy_line_publishes_no_wrong_value_and_keeps_totals_exact() {
    let broker = Broker::start();
    let plant = plant(
        r#"
[buses.line1]
line = { baud = 19200, turnaround = "3ms", drop = 0.05, corrupt = 0.01 }
[buses.line1.devices.a]
unit = 1
model = "wj157"
modes = [0]
channels.enc0 = { rate = 700.0 }
[buses.line1.devices.b]
unit = 2
model = "wj157"
modes = [1]
channels.a0 = { count = 4294960000, rate = 300.0 }
channels.b0 = { rate = 45.0 }
[buses.line1.devices.c]
unit = 3
model = "yl67"
channels.enc1 = { rate = 120.0 }
"#,
    )
    .await;
    // The plant's clock against the wall clock, to look up what each module held at a reading.
    let (wall0, sim0) = (std::time::SystemTime::now(), plant.now());
    let dir = temp_dir("noisy");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "wj157", "200ms"),
        ("line1", "b", 2, "wj157", "200ms"),
        ("line1", "c", 3, "yl67", "200ms"),
    ];
    let _gw = start_gateway(
        &plant,
        broker.port,
        &dir,
        &devices,
        "[buses.line1.devices.a.channels.enc0]\nmax_rate_hz = 1000\n",
    );
    let channels = [
        ("a", 1u8, "enc0", 700.0),
        ("b", 2, "a0", 300.0),
        ("b", 2, "b0", 45.0),
        ("c", 3, "enc1", 120.0),
    ];
    // At 5% lost bytes a module whose poll takes several requests may get few good polls in
    // the soak; an unlucky run goes on (at most 3 minutes more) until every channel has shown two
    // readings, so that the exact-total check below always has something to compare.
    tokio::time::sleep(soak()).await;
    let extended = Instant::now();
    while extended.elapsed() < Duration::from_secs(180)
        && channels
            .iter()
            .any(|(dev, _, ch, _)| readings(&sub, &format!("pulsegate/test/{dev}/{ch}")).len() < 2)
    {
        tokio::time::sleep(Duration::from_millis(500)).await;
    }
    for (_, unit, ch, _) in channels {
        plant
            .with_module("line1", unit, |m, now| m.set_rate(now, ch, 0.0))
            .unwrap();
    }
    let stopped = Instant::now();
    let stopped_at = plant.now();
    for (dev, unit, ch, rate) in channels {
        let topic = format!("pulsegate/test/{dev}/{ch}");
        // At 5% lost bytes most frames break: a good one may take a while.
        let last = sub
            .wait_for(&topic, Duration::from_secs(180), |m| {
                m.at > stopped + Duration::from_millis(300)
            })
            .await
            .unwrap_or_else(|| panic!("{topic}: no reading after the pulses stopped"))
            .json();
        let all = readings(&sub, &topic);
        assert!(
            all.len() >= 2,
            "{topic}: only {} readings got through",
            all.len()
        );

        // Totals exact: the pulses since the gateway's first reading.
        let generated = plant
            .with_module("line1", unit, |m, now| {
                m.channel(ch).unwrap().generated(now)
            })
            .unwrap();
        let at_first = (all[0]["count"].as_i64().unwrap() - start_count(ch)).rem_euclid(1 << 32);
        let total = last["total"].as_i64().unwrap();
        assert_eq!(
            total,
            generated - at_first,
            "{topic}: total against pulses generated since the first reading"
        );

        // No wrong value: each published count is what the module held just before the answer
        // arrived (the line takes a few ms; a retried poll a little more).
        for r in &all {
            let ts = humantime::parse_rfc3339(r["ts"].as_str().unwrap()).unwrap();
            let at =
                (sim0 + ts.duration_since(wall0).unwrap_or_default().as_secs_f64()).min(stopped_at);
            let expected = start_count(ch) + (rate * at).floor() as i64;
            let diff = (expected - r["count"].as_i64().unwrap()).rem_euclid(1 << 32);
            let diff = if diff >= 1 << 31 {
                diff - (1 << 32)
            } else {
                diff
            };
            let slack = rate * 0.02 + 2.0;
            assert!(
                (-slack..=rate * 0.5 + 2.0).contains(&(diff as f64)),
                "{topic}: published count {} at {at:.3}s, the module held about {expected}",
                r["count"]
            );
        }
    }
}

fn start_count(ch: &str) -> i64 {
    if ch == "a0" { 4_294_960_000 } else { 0 }
}

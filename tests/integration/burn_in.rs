//! Burn-in: the long real-time scenarios (a noisy line, a broker away). They prove the real thing
//! end to end: a real broker's reconnect, a real line's noise, which paused time cannot show. Each
//! holds its fault until what it is about has happened and no longer (the spool holds so many
//! readings, the reads were shortened and every channel published through the noise), with
//! generous deadlines for a loaded machine; the minute-long versions of the same logic run on
//! tokio's paused clock in `src/` (`publish/mqtt/paused_tests.rs`, `bus/availability_tests.rs`).
//! `PULSEGATE_NOISE_SECS` and `PULSEGATE_SOAK_SECS` hold the noisy ones at least that long.
//! They live in this module because libtest starts tests in name order: `burn_in::` sorts first,
//! so the long ones start at once, side by side, and the suite's wall time is the longest of them
//! rather than whatever they queued behind.

use std::time::{Duration, Instant};

use crate::faults::a_broker_away_loses_no_reading;
use crate::protocol::Protocol;
use crate::support::*;

/// Away until a thousand readings are spooled (about ten seconds, ten reconnect attempts); a
/// minute's outage of the same spool runs on paused time in `src/publish/mqtt/paused_tests.rs`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_away_until_a_thousand_readings_spool_loses_none_and_keeps_their_order() {
    a_broker_away_loses_no_reading(Protocol::V5, 1000).await;
}

/// Metering's whole story in five-second records: a broker outage with a power cycle in it, a
/// gateway stop over a boundary and a crash mid-interval (body in `metering`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metering_records_through_a_stop_an_outage_and_a_power_cycle() {
    crate::metering::five_second_records_tile_time_and_match_the_simulator_through_a_stop_an_outage_and_a_power_cycle().await;
}

/// JSON and Sparkplug B side by side through an outage of the SCADA broker (body in `outputs`).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn outputs_the_scada_broker_away() {
    crate::outputs::the_scada_broker_away_costs_json_nothing_and_sparkplug_no_pulse().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn outputs_a_primary_host_offline_holds_sparkplug_only() {
    crate::outputs::a_primary_host_offline_holds_sparkplug_only().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sparkplug_historical_readings_after_an_outage() {
    crate::sparkplug::after_a_broker_outage_the_historical_readings_follow_the_rebirth_in_order()
        .await;
}

// The longest of the other modules' tests (20-35 s on a quiet machine), run from here so that
// they start with the rest of the long runs instead of queueing behind the short ones of their
// own module (bodies and their docs in the named modules).

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn hostile_twenty_sigkills_at_random_moments() {
    crate::hostile::twenty_sigkills_at_random_moments_never_reuse_a_seq().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn metering_many_devices_due_at_one_boundary() {
    crate::metering::many_devices_due_at_one_boundary_are_read_at_once_and_other_devices_keep_their_rate().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn outputs_ten_thousand_dcmds_in_a_burst() {
    crate::outputs::ten_thousand_dcmds_in_a_burst_are_each_answered_or_counted().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn readings_first_a_flood_of_home_assistant_births() {
    crate::readings_first::a_flood_of_home_assistant_births_costs_no_reading_and_no_disk().await;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn signed_every_record_verifies_with_openssl() {
    crate::signed::every_record_verifies_with_openssl_against_the_published_key_and_verify_finds_tampering().await;
}

/// 2% of the bytes corrupted, both ways, at 9600 baud until 60 bytes were corrupted and every
/// device answered ten times through it (about 15 s; `PULSEGATE_NOISE_SECS` holds it longer):
/// CRC errors and undecodable frames are garbled answers, not line faults, and no device goes
/// offline.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_percent_corrupted_bytes_at_9600_baud_take_no_device_offline() {
    let at_least = std::env::var("PULSEGATE_NOISE_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .map_or(Duration::ZERO, Duration::from_secs);
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
    let noisy = Instant::now();
    let corrupted = || {
        plant
            .bus("line1")
            .unwrap()
            .line
            .as_ref()
            .unwrap()
            .counters
            .corrupted
            .load(std::sync::atomic::Ordering::Relaxed)
    };
    let per_device = || -> Vec<usize> {
        ["a/enc0", "b/enc0", "c/a0"]
            .iter()
            .map(|d| {
                let on = sub.on(&format!("pulsegate/test/{d}"));
                on.iter().filter(|m| m.at > noisy).count()
            })
            .collect()
    };
    let enough = || {
        corrupted() >= 60 && per_device().iter().all(|&n| n >= 10) && noisy.elapsed() >= at_least
    };
    until(
        Duration::from_secs(120),
        "noise and answers",
        enough,
        || gw.log_text(),
    )
    .await;
    let secs = noisy.elapsed().as_secs_f64();
    let corrupted = corrupted();
    let log = gw.log_text();
    let garbled = log.matches("garbled answer").count();
    println!(
        "noise: {corrupted} bytes corrupted in {secs:.1} s; {garbled} garbled-answer log lines"
    );
    assert!(corrupted >= 60, "the line was noisy: {corrupted}");
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
    let bound = 3 * (secs as usize / 60 + 2);
    println!("noise: {error_lines} error lines from the devices (bound {bound})");
    assert!(error_lines <= bound, "{error_lines} error lines:\n{log}");
    // The line is saturated at 9600 baud (the YL67's poll alone reads 160 registers, and noisy
    // reads are asked again): readings come slower than the 500 ms asked, but they come.
    let counts = per_device();
    println!("noise: readings per device {counts:?}");
    assert!(
        counts.iter().all(|&n| n as f64 >= secs / 3.0),
        "{counts:?} in {secs:.1} s"
    );
}

/// How long the noisy-line scenario holds its noise at the least: nothing by default (the noise
/// lasts until the reads were shortened and every channel published through it);
/// `PULSEGATE_SOAK_SECS` runs a longer soak, e.g. 600.
fn soak() -> Duration {
    std::env::var("PULSEGATE_SOAK_SECS")
        .ok()
        .and_then(|s| s.parse().ok())
        .map_or(Duration::ZERO, Duration::from_secs)
}

const NOISY_PLANT: &str = r#"
[buses.line1]
line = { baud = 19200, turnaround = "3ms", drop = 0.03, corrupt = 0.01, seed = 23 }
[buses.line1.devices.a]
unit = 1
model = "yl67"
channels = { enc0 = { rate = 120.0 }, enc1 = { rate = 80.0 }, enc2 = { rate = 15.0 }, enc3 = { rate = 3.0 } }
[buses.line1.devices.b]
unit = 2
model = "wj157"
modes = [1]
channels.a0 = { count = 4294960000, rate = 300.0 }
channels.b0 = { rate = 45.0 }
[buses.line1.devices.c]
unit = 3
model = "zh-yx1600"
"#;

/// Every channel of the noisy plant: (device, unit, channel, pulses per second).
fn noisy_channels() -> Vec<(&'static str, u8, String, f64)> {
    let mut out = vec![
        ("a", 1, "enc0".to_string(), 120.0),
        ("a", 1, "enc1".into(), 80.0),
        ("a", 1, "enc2".into(), 15.0),
        ("a", 1, "enc3".into(), 3.0),
        ("b", 2, "a0".into(), 300.0),
        ("b", 2, "b0".into(), 45.0),
    ];
    out.extend((1..=16).map(|i| ("c", 3, format!("di{i}"), f64::from(i) * 7.0)));
    out
}

/// Bus stats of `line1` that arrived after `after` and satisfy `f`, waiting up to `within`.
async fn stats_where(
    sub: &Subscriber,
    after: Instant,
    within: Duration,
    f: impl Fn(&serde_json::Value) -> bool,
) -> Option<serde_json::Value> {
    sub.wait_for("pulsegate/test/bus/line1/stats", within, |m| {
        m.at > after && f(&m.json())
    })
    .await
    .map(|m| m.json())
}

/// 3% dropped and 1% corrupted bytes (seeded, even noise) at 19200 baud until the reads were
/// shortened and every channel published four readings through it (about 20 s): a module whose
/// poll reads a 64-register block (the ZH-YX1600) gets its reads shortened and keeps publishing
/// every channel, whole (no wrong count, totals exact); when the noise stops, the reads grow back
/// to the full block and the line use to its clean figure.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_noisy_line_shortens_reads_publishes_every_channel_exactly_and_grows_them_back() {
    let broker = Broker::start();
    let plant = plant(NOISY_PLANT).await;
    let line = || plant.bus("line1").unwrap().line.as_ref().unwrap();
    line().set_noisy(false);
    for (_, unit, ch, rate) in noisy_channels().into_iter().filter(|c| c.0 == "c") {
        plant
            .with_module("line1", unit, |m, now| m.set_rate(now, &ch, rate))
            .unwrap();
    }
    let (wall0, sim0) = (std::time::SystemTime::now(), plant.now());
    let dir = temp_dir("noisy");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "yl67", "500ms"),
        ("line1", "b", 2, "wj157", "500ms"),
        ("line1", "c", 3, "zh-yx1600", "500ms"),
    ];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "")
        .replace("baud = 115200", "baud = 19200")
        .replace(
            "state_flush = \"500ms\"",
            "state_flush = \"500ms\"\nstats_interval = \"2s\"",
        );
    let gw = Gateway::start(&write_config(&dir, &text));

    // Clean: every poll in full blocks (the ZH-YX1600: its 16 command words and a 64-register
    // block of counts and windows).
    let full = |s: &serde_json::Value, d: &str| s["devices"][d]["request_limit"] == 125;
    let clean = stats_where(&sub, Instant::now(), Duration::from_secs(30), |s| {
        ["a", "b", "c"].iter().all(|d| full(s, d)) && s["devices"]["c"]["longest_request"] == 64
    })
    .await
    .unwrap_or_else(|| panic!("clean stats:\n{}", gw.log_text()));
    let clean_use = clean["utilisation"].as_f64().unwrap();
    let clean_requests = clean["devices"]["c"]["requests_per_poll"].clone();

    line().set_noisy(true);
    let noisy = Instant::now();
    let shortened = stats_where(&sub, noisy, Duration::from_secs(60), |s| {
        s["devices"]["c"]["request_limit"].as_u64() < Some(64)
    })
    .await
    .unwrap_or_else(|| {
        panic!(
            "the ZH-YX1600's reads were not shortened:\n{}",
            gw.log_text()
        )
    });
    println!("noise: shortened {:?}", shortened["devices"]["c"]);
    // The noise holds until every channel published through it (and the soak asked for).
    let during = |until: Instant| -> Vec<(String, usize)> {
        noisy_channels()
            .into_iter()
            .map(|(dev, _, ch, _)| {
                let topic = format!("pulsegate/test/{dev}/{ch}");
                let n = sub
                    .on(&topic)
                    .iter()
                    .filter(|m| m.at > noisy && m.at <= until)
                    .count();
                (topic, n)
            })
            .collect()
    };
    let published = || during(Instant::now()).iter().all(|(_, n)| *n >= 4);
    let held = || published() && noisy.elapsed() >= soak();
    until(
        Duration::from_secs(90),
        "every channel through the noise",
        held,
        || format!("{:?}\n{}", during(Instant::now()), gw.log_text()),
    )
    .await;
    line().set_noisy(false);
    let quiet = Instant::now();
    let counters = &line().counters;
    let (dropped, corrupted) = (
        counters.dropped.load(std::sync::atomic::Ordering::Relaxed),
        counters
            .corrupted
            .load(std::sync::atomic::Ordering::Relaxed),
    );
    println!(
        "noise: {dropped} bytes dropped, {corrupted} corrupted in {:?}",
        quiet - noisy
    );

    // Every channel kept publishing through the noise.
    let during = during(quiet);
    println!("noise: readings per channel {during:?}");
    for (topic, n) in &during {
        assert!(
            *n >= 4,
            "{topic}: {n} readings in {:?} of noise",
            quiet - noisy
        );
    }

    // The reads grow back to the full block within a minute, and the line use with them.
    let grown = stats_where(&sub, quiet, Duration::from_secs(60), |s| {
        ["a", "b", "c"].iter().all(|d| full(s, d))
            && s["devices"]["c"]["longest_request"] == 64
            && s["devices"]["c"]["requests_per_poll"] == clean_requests
            && s["utilisation"].as_f64().unwrap() <= clean_use * 1.25 + 0.02
    })
    .await
    .unwrap_or_else(|| {
        panic!(
            "reads did not grow back (clean use {clean_use}):\n{}",
            gw.log_text()
        )
    });
    println!(
        "noise: clean again after {:?} (line use {clean_use:.3} clean, {:.3} now)",
        quiet.elapsed(),
        grown["utilisation"]
    );

    every_reading_is_the_modules_count(&plant, &sub, (wall0, sim0)).await;
}

/// Stops every input; then each channel's published counts are what the module held at their
/// time, each delta is the step between two counts, and the last total is every pulse the
/// module counted since the gateway's first reading.
async fn every_reading_is_the_modules_count(
    plant: &pulsegate::sim::Plant,
    sub: &Subscriber,
    (wall0, sim0): (std::time::SystemTime, f64),
) {
    for (_, unit, ch, _) in noisy_channels() {
        plant
            .with_module("line1", unit, |m, now| m.set_rate(now, &ch, 0.0))
            .unwrap();
    }
    let stopped = Instant::now();
    let stopped_at = plant.now();
    for (dev, unit, ch, rate) in noisy_channels() {
        let topic = format!("pulsegate/test/{dev}/{ch}");
        sub.wait_for(&topic, Duration::from_secs(20), |m| {
            m.at > stopped + Duration::from_millis(300)
        })
        .await
        .unwrap_or_else(|| panic!("{topic}: no reading after the pulses stopped"));
        let all = readings(sub, &topic);
        let held = plant
            .with_module("line1", unit, |m, now| m.channel(&ch).unwrap().count(now))
            .unwrap();
        let wrap = |d: i64| {
            let d = d.rem_euclid(1 << 32);
            if d >= 1 << 31 { d - (1 << 32) } else { d }
        };
        let count = |r: &serde_json::Value| r["count"].as_i64().unwrap();
        let last = all.last().unwrap();
        assert_eq!(wrap(count(last) - held), 0, "{topic}: last count");
        assert_eq!(
            last["total"].as_i64().unwrap() - all[0]["total"].as_i64().unwrap(),
            wrap(count(last) - count(&all[0])),
            "{topic}: total against the module's count since the first reading"
        );
        for w in all.windows(2) {
            assert_eq!(
                w[1]["delta"].as_i64().unwrap(),
                wrap(count(&w[1]) - count(&w[0])),
                "{topic}: delta between {} and {}",
                w[0],
                w[1]
            );
        }
        // Each count is what the module held just before the answer arrived: the count at the
        // stop less the pulses since (the line takes a few ms; a retried read a little more).
        for r in &all {
            let ts = humantime::parse_rfc3339(r["ts"].as_str().unwrap()).unwrap();
            let at =
                (sim0 + ts.duration_since(wall0).unwrap_or_default().as_secs_f64()).min(stopped_at);
            let expected = (held - (rate * (stopped_at - at)) as i64).max(start_count(&ch));
            let diff = wrap(expected - count(r));
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

//! The wall clock steps and long outages, end to end: the gateway runs under libfaketime (wall
//! clock faked, monotonic clock left real) against the simulator on a pseudo-terminal.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;
use serde_json::Value;

use crate::support::*;

/// libfaketime, from the Debian package `libfaketime` (scripts/test installs it).
fn libfaketime() -> &'static str {
    [
        "/usr/lib/x86_64-linux-gnu/faketime/libfaketime.so.1",
        "/usr/lib/aarch64-linux-gnu/faketime/libfaketime.so.1",
        "/usr/lib/faketime/libfaketime.so.1",
    ]
    .into_iter()
    .find(|p| Path::new(p).exists())
    .expect("libfaketime is not installed: run the README's test command (scripts/test)")
}

/// Starts the gateway with its wall clock read from `rc` (a libfaketime offset such as "+0"
/// or "-3600"), re-read every call; the monotonic clock is left real.
fn start_faked(config: &Path, rc: &Path) -> Gateway {
    Gateway::start_with_env(
        config,
        &[
            ("LD_PRELOAD", libfaketime()),
            ("FAKETIME_TIMESTAMP_FILE", rc.to_str().unwrap()),
            ("FAKETIME_NO_CACHE", "1"),
            ("FAKETIME_DONT_FAKE_MONOTONIC", "1"),
        ],
    )
}

fn set_rate(plant: &Plant, unit: u8, ch: &str, rate: f64) {
    plant
        .with_module("line1", unit, |m, now| assert!(m.set_rate(now, ch, rate)))
        .unwrap();
}

fn generated(plant: &Plant, unit: u8, ch: &str) -> i64 {
    plant
        .with_module("line1", unit, |m, now| {
            m.channel(ch).unwrap().generated(now)
        })
        .unwrap()
}

/// Waits for a reading on `topic` that arrived after `after`.
async fn reading_after(sub: &Subscriber, topic: &str, after: Instant) -> Value {
    sub.wait_for(topic, Duration::from_secs(10), |m| m.at > after)
        .await
        .unwrap_or_else(|| panic!("a reading on {topic}"))
        .json()
}

fn ts_of(r: &Value) -> std::time::SystemTime {
    humantime::parse_rfc3339(r["ts"].as_str().unwrap()).unwrap()
}

fn events(sub: &Subscriber, topic: &str, name: &str) -> usize {
    readings(sub, topic)
        .iter()
        .filter(|r| r["event"] == name)
        .count()
}

struct Setup {
    broker: Broker,
    plant: Plant,
    dir: PathBuf,
    config: PathBuf,
    rc: PathBuf,
    sub: Subscriber,
}

async fn setup(name: &str, sim: &str, devices: &[(&str, &str, u8, &str, &str)]) -> Setup {
    let broker = Broker::start();
    let plant = plant(sim).await;
    let dir = temp_dir(name);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let config = write_config(&dir, &gateway_toml(&plant, broker.port, &dir, devices, ""));
    let rc = dir.join("faketime.rc");
    std::fs::write(&rc, "+0\n").unwrap();
    Setup {
        broker,
        plant,
        dir,
        config,
        rc,
        sub,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_wall_clock_stepped_back_and_forward_an_hour_mid_run_moves_the_total_as_the_module_counts()
 {
    let s = setup(
        "clock-step",
        "[buses.line1.devices.dev]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n",
        &[("line1", "dev", 1, "yl67", "200ms")],
    )
    .await;
    let topic = "pulsegate/test/dev/a0";
    let gateway = start_faked(&s.config, &s.rc);
    reading_after(&s.sub, topic, Instant::now()).await;
    set_rate(&s.plant, 1, "a0", 2000.0);
    s.sub
        .wait_for(topic, Duration::from_secs(10), |m| {
            m.json()["total"].as_i64() > Some(2000)
        })
        .await
        .expect("counting");

    // An hour back.
    std::fs::write(&s.rc, "-3600\n").unwrap();
    let stepped = Instant::now();
    let behind = reading_after(&s.sub, topic, stepped + Duration::from_millis(500)).await;
    let lag = std::time::SystemTime::now()
        .duration_since(ts_of(&behind))
        .unwrap_or_default();
    assert!(
        lag > Duration::from_secs(3500),
        "the gateway's wall clock did step back: {behind}"
    );

    // And an hour forward again.
    std::fs::write(&s.rc, "+0\n").unwrap();
    let forward = Instant::now();
    reading_after(&s.sub, topic, forward + Duration::from_millis(500)).await;
    reading_after(&s.sub, topic, forward + Duration::from_millis(1000)).await;
    set_rate(&s.plant, 1, "a0", 0.0);
    let last = reading_after(&s.sub, topic, Instant::now() + Duration::from_millis(500)).await;
    assert_eq!(
        last["total"].as_i64().unwrap(),
        generated(&s.plant, 1, "a0"),
        "total moves exactly as the module's count"
    );
    assert_eq!(events(&s.sub, topic, "reset"), 0, "no reset");
    assert_eq!(events(&s.sub, topic, "rollover"), 0, "no rollover");
    drop(gateway);
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn two_days_away_a_power_cycled_slow_channel_books_its_count_since_power_up_and_a_fast_one_its_wrap()
 {
    let s = setup(
        "two-days",
        "[buses.line1.devices.slow]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n\
         [buses.line1.devices.fast]\nunit = 2\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n",
        &[
            ("line1", "slow", 1, "yl67", "100ms"),
            ("line1", "fast", 2, "yl67", "100ms"),
        ],
    )
    .await;
    let (slow, fast) = ("pulsegate/test/slow/a0", "pulsegate/test/fast/a0");
    let gateway = start_faked(&s.config, &s.rc);
    reading_after(&s.sub, slow, Instant::now()).await;
    reading_after(&s.sub, fast, Instant::now()).await;
    set_rate(&s.plant, 1, "a0", 100.0);
    set_rate(&s.plant, 2, "a0", 40_000.0);
    s.sub
        .wait_for(fast, Duration::from_secs(10), |m| {
            m.json()["count"].as_i64() > Some(60_000)
        })
        .await
        .expect("the fast channel counting");
    set_rate(&s.plant, 1, "a0", 0.0);
    set_rate(&s.plant, 2, "a0", 0.0);
    let settled = Instant::now() + Duration::from_millis(400);
    let slow_before = reading_after(&s.sub, slow, settled).await;
    let fast_before = reading_after(&s.sub, fast, settled).await;
    gateway.terminate();

    // Away two days: the slow module lost power and has counted 18 since; the fast one went
    // all the way round and stands 50_000 below where it was.
    s.plant
        .with_module("line1", 1, |m, now| {
            m.power_cycle(now);
            m.set_count(now, "a0", 18);
        })
        .unwrap();
    let fast_count = fast_before["count"].as_i64().unwrap();
    let fast_now = fast_count - 50_000;
    assert!(fast_now > 0, "the fast channel counted more than 50_000");
    s.plant
        .with_module("line1", 2, |m, now| m.set_count(now, "a0", fast_now))
        .unwrap();
    std::fs::write(&s.rc, "+2d\n").unwrap();
    let restarted = Instant::now();
    let gateway = start_faked(&s.config, &s.rc);
    let slow_after = reading_after(&s.sub, slow, restarted).await;
    let fast_after = reading_after(&s.sub, fast, restarted).await;

    let slow_total = slow_before["total"].as_i64().unwrap();
    assert_eq!(
        slow_after["total"].as_i64().unwrap(),
        slow_total + 18,
        "the count since power-up, not a wrap: {slow_after}"
    );
    assert!(
        ["reset", "gap"].contains(&slow_after["event"].as_str().unwrap_or("")),
        "{slow_after}"
    );
    assert_eq!(
        fast_after["delta"].as_i64().unwrap(),
        (1i64 << 32) - 50_000,
        "the fast channel's wrap is booked: {fast_after}"
    );
    assert_eq!(fast_after["event"], "gap");
    let ahead = ts_of(&fast_after)
        .duration_since(std::time::SystemTime::now())
        .unwrap_or_default();
    assert!(
        ahead > Duration::from_secs(47 * 3600),
        "the gateway came back two days later"
    );
    drop(gateway);
    let _ = (&s.broker, &s.dir, fast_count);
}

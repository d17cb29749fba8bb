//! Counter truth end to end: the simulator counts pulses on a pseudo-terminal, the gateway
//! publishes to Mosquitto, and the test compares the published totals with the pulses the
//! simulator generated.
//!
//! Each scenario starts its channel at rate 0, waits for the gateway's first reading (the
//! baseline), runs pulses, and stops them again before comparing, so "pulses generated" and
//! "total" cover the same span exactly.

use std::time::{Duration, Instant};

use pulsegate::sim::Plant;
use serde_json::Value;

use crate::support::*;

/// A plant with one bus `line1`, the gateway polling its unit 1 as `dev` every 100 ms.
struct Rig {
    broker: Broker,
    plant: Plant,
    dir: std::path::PathBuf,
    config: std::path::PathBuf,
    sub: Subscriber,
    gateway: Option<Gateway>,
    topic: String,
}

impl Rig {
    /// `setup` is the simulated channel's TOML, e.g. `count = 5, ppr = 360`.
    async fn start(name: &str, model: &str, modes: &str, channel: &str, setup: &str) -> Rig {
        let broker = Broker::start();
        let plant = plant(&format!(
            "[buses.line1.devices.dev]\nunit = 1\nmodel = {model:?}\nmodes = {modes}\nchannels.{channel} = {{ {setup} }}\n"
        ))
        .await;
        let dir = temp_dir(name);
        let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
        let text = gateway_toml(
            &plant,
            broker.port,
            &dir,
            &[("line1", "dev", 1, model, "100ms")],
            "",
        );
        let config = write_config(&dir, &text);
        let gateway = Some(Gateway::start(&config));
        let topic = format!("pulsegate/test/dev/{channel}");
        let rig = Rig {
            broker,
            plant,
            dir,
            config,
            sub,
            gateway,
            topic,
        };
        rig.sub
            .wait_for(&rig.topic, Duration::from_secs(3), |_| true)
            .await
            .expect("first reading (the baseline)");
        rig
    }

    fn channel(&self) -> String {
        self.topic.rsplit('/').next().unwrap().to_string()
    }

    fn set_rate(&self, rate: f64) {
        let ch = self.channel();
        self.plant
            .with_module("line1", 1, |m, now| assert!(m.set_rate(now, &ch, rate)))
            .unwrap();
    }

    fn generated(&self) -> i64 {
        let ch = self.channel();
        self.plant
            .with_module("line1", 1, |m, now| m.channel(&ch).unwrap().generated(now))
            .unwrap()
    }

    /// Stops the pulses and waits for a reading taken well after, so nothing is in flight.
    async fn stop_and_settle(&self) -> Value {
        self.set_rate(0.0);
        let after = Instant::now() + Duration::from_millis(400);
        let m = self
            .sub
            .wait_for(&self.topic, Duration::from_secs(5), |m| m.at > after)
            .await
            .expect("a reading after the pulses stopped");
        m.json()
    }

    fn readings(&self) -> Vec<Value> {
        readings(&self.sub, &self.topic)
    }

    /// Waits (up to 10 s) for a reading arriving from now on that satisfies `pred`, `what` if
    /// none does.
    async fn reading_where(&self, what: &str, pred: impl Fn(&Value) -> bool) -> Value {
        let since = Instant::now();
        self.sub
            .wait_for(&self.topic, Duration::from_secs(10), |m| {
                m.at >= since && pred(&m.json())
            })
            .await
            .unwrap_or_else(|| panic!("{what}: {:?}", self.readings()))
            .json()
    }

    fn events(&self, name: &str) -> usize {
        self.readings()
            .iter()
            .filter(|r| r["event"] == name)
            .count()
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_di_count_wrapping_at_2_pow_32_keeps_every_delta_positive_and_the_total_exact() {
    let rig = Rig::start("wrap-di", "wj157", "[1]", "a0", "count = 4294967000").await;
    rig.set_rate(1000.0);
    // 296 pulses short of 2^32: the wrap comes within half a second; two readings past it.
    let wrapped = rig
        .reading_where("the rollover", |r| r["event"] == "rollover")
        .await;
    let seq = wrapped["seq"].as_i64().unwrap();
    rig.reading_where("two readings past the rollover", |r| {
        r["seq"].as_i64() >= Some(seq + 2)
    })
    .await;
    let last = rig.stop_and_settle().await;
    let generated = rig.generated();
    let readings = rig.readings();
    assert!(
        readings.iter().all(|r| r["delta"].as_i64().unwrap() >= 0),
        "a negative delta"
    );
    let sum: i64 = readings.iter().map(|r| r["delta"].as_i64().unwrap()).sum();
    assert!(generated > 296, "generated {generated}");
    assert_eq!(sum, generated, "sum of deltas");
    assert_eq!(last["total"].as_i64().unwrap(), generated, "total");
    assert!(
        last["count"].as_i64().unwrap() < 10_000,
        "the count wrapped"
    );
    assert_eq!(rig.events("rollover"), 1);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_encoder_crossing_the_i32_boundary_forwards_and_back_keeps_its_total_exact() {
    let rig = Rig::start(
        "wrap-enc",
        "yl67",
        "[0, 0, 0, 0]",
        "enc0",
        "count = 2147483000",
    )
    .await;
    rig.set_rate(1000.0);
    rig.reading_where("crossed forwards", |r| r["count"].as_i64() < Some(0))
        .await;
    let forward = rig.stop_and_settle().await;
    assert!(
        forward["count"].as_i64().unwrap() < 0,
        "crossed +2147483647 forwards: {forward}"
    );
    assert_eq!(forward["total"].as_i64().unwrap(), rig.generated());
    rig.set_rate(-1000.0);
    rig.reading_where("crossed back", |r| r["count"].as_i64() > Some(0))
        .await;
    let back = rig.stop_and_settle().await;
    assert!(back["count"].as_i64().unwrap() > 0, "crossed back: {back}");
    assert_eq!(back["total"].as_i64().unwrap(), rig.generated());
    assert_eq!(rig.events("rollover"), 2);
    assert_eq!(rig.events("reset"), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_power_cycle_is_one_reset_and_the_total_stays_exact() {
    let rig = Rig::start("power", "yl67", "[1, 1, 1, 1]", "a0", "count = 0").await;
    rig.set_rate(800.0);
    rig.reading_where("counting", |r| r["total"].as_i64() > Some(400))
        .await;
    rig.stop_and_settle().await;
    rig.plant
        .with_module("line1", 1, |m, now| m.power_cycle(now))
        .unwrap();
    rig.set_rate(800.0);
    let reset = rig
        .reading_where("the reset", |r| r["event"] == "reset")
        .await;
    let seq = reset["seq"].as_i64().unwrap();
    rig.reading_where("counting after the reset", |r| {
        r["seq"].as_i64() >= Some(seq + 3)
    })
    .await;
    let last = rig.stop_and_settle().await;
    assert_eq!(rig.events("reset"), 1, "exactly one reset event");
    assert_eq!(last["total"].as_i64().unwrap(), rig.generated());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn one_injected_read_of_zero_leaves_the_total_unaffected() {
    let rig = Rig::start("glitch", "yl67", "[1, 1, 1, 1]", "a0", "count = 1000000").await;
    rig.set_rate(500.0);
    rig.reading_where("counting", |r| r["total"].as_i64() > Some(100))
        .await;
    rig.plant
        .with_module("line1", 1, |m, _| m.glitch_zero.push("a0".into()))
        .unwrap();
    let consumed = || {
        rig.plant
            .with_module("line1", 1, |m, _| m.glitch_zero.is_empty())
            .unwrap()
    };
    until(Duration::from_secs(10), "the glitch read", consumed, || {
        format!("{:?}", rig.readings())
    })
    .await;
    let glitched = Instant::now();
    rig.sub
        .wait_for(&rig.topic, Duration::from_secs(10), |m| m.at > glitched)
        .await
        .expect("a reading after the glitch");
    let last = rig.stop_and_settle().await;
    let consumed = rig
        .plant
        .with_module("line1", 1, |m, _| m.glitch_zero.is_empty())
        .unwrap();
    assert!(consumed, "the glitch reached the gateway");
    let readings = rig.readings();
    assert!(
        readings.iter().all(|r| r["count"] != 0),
        "the odd read is not published"
    );
    let seqs: Vec<i64> = readings
        .iter()
        .map(|r| r["seq"].as_i64().unwrap())
        .collect();
    assert!(
        seqs.windows(2).all(|w| w[1] == w[0] + 1),
        "seq has no hole: {seqs:?}"
    );
    assert_eq!(last["total"].as_i64().unwrap(), rig.generated());
    assert_eq!(rig.events("reset"), 0);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_gateway_killed_and_down_while_2000_pulses_count_books_them_once() {
    let mut rig = Rig::start("sigkill", "yl67", "[1, 1, 1, 1]", "a0", "count = 0").await;
    rig.set_rate(1000.0);
    rig.reading_where("counting", |r| r["total"].as_i64() > Some(1000))
        .await;
    rig.gateway.take().unwrap().kill();
    let at_kill = rig.generated();
    until(
        Duration::from_secs(20),
        "2000 pulses while the gateway is down",
        || rig.generated() >= at_kill + 2000,
        String::new,
    )
    .await;
    let restarted = Instant::now();
    rig.gateway = Some(Gateway::start(&rig.config));
    let first = rig
        .sub
        .wait_for(&rig.topic, Duration::from_secs(5), |m| m.at > restarted)
        .await
        .expect("readings after the restart");
    let seq = first.json()["seq"].as_i64().unwrap();
    rig.reading_where("readings after the restart", |r| {
        r["seq"].as_i64() >= Some(seq + 3)
    })
    .await;
    let last = rig.stop_and_settle().await;
    assert_eq!(
        last["total"].as_i64().unwrap(),
        rig.generated(),
        "total after SIGKILL and restart"
    );
    assert_eq!(rig.events("gap"), 1, "one gap event");
    let _ = (&rig.broker, &rig.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn frequency_is_within_1_percent_and_rpm_follows_pulses_per_revolution() {
    let rig = Rig::start(
        "freq",
        "yl67",
        "[0, 0, 0, 0]",
        "enc0",
        "count = 0, ppr = 360",
    )
    .await;
    rig.set_rate(2500.0);
    let t0 = Instant::now() + Duration::from_millis(300);
    // Twenty readings polled 100 ms apart: two seconds of the rate.
    let n = |rig: &Rig| rig.sub.on(&rig.topic).iter().filter(|m| m.at > t0).count();
    until(
        Duration::from_secs(20),
        "twenty readings",
        || n(&rig) >= 20,
        || format!("{:?}", rig.readings()),
    )
    .await;
    let window: Vec<Value> = rig
        .sub
        .on(&rig.topic)
        .into_iter()
        .filter(|m| m.at > t0)
        .map(|m| m.json())
        .collect();
    assert!(window.len() >= 10);
    for r in &window {
        let f = r["freq_hz"].as_f64().unwrap();
        assert!((f - 2500.0).abs() <= 25.0, "freq_hz {f}");
        let rpm = r["rpm"].as_f64().unwrap();
        assert!(
            (rpm - f * 60.0 / 360.0).abs() < 0.01,
            "rpm {rpm} for freq_hz {f} at 360 ppr"
        );
    }
    // The derived rate over the whole window, independent of the module's register.
    let first = &window[0];
    let last = window.last().unwrap();
    let pulses = (last["total"].as_i64().unwrap() - first["total"].as_i64().unwrap()) as f64;
    let secs = (humantime::parse_rfc3339(last["ts"].as_str().unwrap())
        .unwrap()
        .duration_since(humantime::parse_rfc3339(first["ts"].as_str().unwrap()).unwrap())
        .unwrap())
    .as_secs_f64();
    let rate = pulses / secs;
    assert!((rate - 2500.0).abs() <= 25.0, "derived rate {rate}");
}

/// Paced publishing (`min_interval`) skips readings and carries their deltas to the next one
/// published. A restart in between, clean or not, must not take the carried pulses from a
/// consumer summing deltas: the first reading after it carries them.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_restart_between_paced_readings_loses_no_pulse_for_a_consumer() {
    let mut rig = Rig::start("paced-restart", "yl67", "[1, 1, 1, 1]", "a0", "count = 0").await;
    let (status, _) = rig.gateway.take().unwrap().terminate();
    assert!(status.success());
    let text = std::fs::read_to_string(&rig.config).unwrap();
    let paced = text.replace("[gateway]\n", "[gateway]\nmin_interval = \"3s\"\n");
    assert_ne!(text, paced);
    std::fs::write(&rig.config, paced).unwrap();
    rig.set_rate(200.0);
    // Twice: a clean stop, then a SIGKILL, each about a second and a half after a published
    // reading (so a second and a half of pulses is carried, not yet published).
    for kill in [false, true] {
        let started = Instant::now();
        rig.gateway = Some(Gateway::start(&rig.config));
        let m = rig
            .sub
            .wait_for(&rig.topic, Duration::from_secs(5), |m| m.at > started)
            .await
            .expect("a reading after the start");
        let next = rig
            .sub
            .wait_for(&rig.topic, Duration::from_secs(5), |n| n.at > m.at)
            .await
            .expect("a paced reading");
        tokio::time::sleep_until((next.at + Duration::from_millis(1500)).into()).await;
        let gw = rig.gateway.take().unwrap();
        if kill {
            gw.kill();
        } else {
            assert!(gw.terminate().0.success());
        }
    }
    let started = Instant::now();
    rig.gateway = Some(Gateway::start(&rig.config));
    rig.sub
        .wait_for(&rig.topic, Duration::from_secs(5), |m| m.at > started)
        .await
        .expect("the reading that carries the pulses");
    let last = rig.stop_and_settle().await;
    let generated = rig.generated();
    let sum: i64 = rig
        .readings()
        .iter()
        .map(|r| r["delta"].as_i64().unwrap())
        .sum();
    assert_eq!(last["total"].as_i64().unwrap(), generated, "total");
    assert_eq!(
        sum,
        generated,
        "the deltas a consumer sums: {:#?}",
        rig.readings()
    );
    let _ = (&rig.broker, &rig.dir);
}

//! Readings first: chatter (discovery re-announcements, refused commands) shares the connection
//! with the readings but can never cost one, and a crash after a broker stall loses no pulse for
//! a consumer following `after_seq`. Real broker, simulated modules on Modbus TCP.

use std::collections::BTreeMap;
use std::time::{Duration, Instant};

use rumqttc::v5::mqttbytes::QoS;

use crate::hostile::{KILLED_ENCODER, consume, stop_and_collect};
use crate::support::*;

/// Three YL67 on Modbus TCP, each counting on `enc0`.
fn three_encoders(port: u16) -> String {
    let mut text = format!("[buses.tcp1]\nlisten = \"127.0.0.1:{port}\"\n");
    for unit in 1..=3 {
        text += &format!(
            "[buses.tcp1.devices.m{unit}]\nunit = {unit}\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = {}.0 }}\n",
            100 * unit
        );
    }
    text
}

/// More devices configured on a bus that nobody answers: with 190, a site of some 250 discovery
/// configs.
fn ghost_bus(devices: u8) -> String {
    let port = free_port();
    let mut text = format!(
        "[buses.ghost]\nhost = \"127.0.0.1\"\nport = {port}\ntimeout = \"100ms\"\nbackoff_max = \"5s\"\n"
    );
    for unit in 1..=devices {
        text += &format!("[buses.ghost.devices.g{unit}]\nunit = {unit}\nmodel = \"yl67\"\n");
    }
    text
}

/// A gateway polling the three encoders every 200 ms with a 1 MB spool, plus `extra`.
async fn rig(
    name: &str,
    broker: &Broker,
    extra: &str,
) -> (pulsegate::sim::Plant, Gateway, Subscriber) {
    let plant = plant(&three_encoders(free_port())).await;
    let dir = temp_dir(name);
    let sub = Subscriber::start(broker.port, "pulsegate/test/+/enc0").await;
    let devices: Vec<(&str, &str, u8, &str, &str)> = (1..=3)
        .map(|u| ("tcp1", ["m1", "m2", "m3"][u - 1], u as u8, "yl67", "200ms"))
        .collect();
    let text = gateway_toml(&plant, broker.port, &dir, &devices, extra).replacen(
        "[mqtt]\n",
        "[mqtt]\nspool_mb = 1\n",
        1,
    );
    let gw = Gateway::start(&write_config(&dir, &text));
    for d in ["m1", "m2", "m3"] {
        sub.expect_any(&format!("pulsegate/test/{d}/enc0"), Duration::from_secs(10))
            .await;
    }
    (plant, gw, sub)
}

/// Every channel's readings: seq without a gap, and deltas that add up to the total's change.
fn assert_every_pulse_counted(sub: &Subscriber) {
    let mut by_topic: BTreeMap<String, Vec<serde_json::Value>> = BTreeMap::new();
    for m in sub.all() {
        by_topic.entry(m.topic.clone()).or_default().push(m.json());
    }
    assert_eq!(by_topic.len(), 3, "{:?}", by_topic.keys());
    for (topic, readings) in by_topic {
        for w in readings.windows(2) {
            let (a, b) = (w[0]["seq"].as_i64().unwrap(), w[1]["seq"].as_i64().unwrap());
            assert_eq!(b, a + 1, "{topic}: seq {a} then {b}");
        }
        let deltas: i64 = readings[1..]
            .iter()
            .map(|r| r["delta"].as_i64().unwrap())
            .sum();
        let first = readings[0]["total"].as_i64().unwrap();
        let last = readings.last().unwrap()["total"].as_i64().unwrap();
        assert_eq!(deltas, last - first, "{topic}: summed deltas");
        assert!(readings.len() > 10, "{topic}: {} readings", readings.len());
    }
}

/// Bytes the process has caused to be written to storage (`/proc/<pid>/io`).
fn disk_writes(pid: i32) -> u64 {
    let io = std::fs::read_to_string(format!("/proc/{pid}/io")).unwrap();
    io.lines()
        .find_map(|l| l.strip_prefix("write_bytes: "))
        .and_then(|v| v.trim().parse().ok())
        .unwrap()
}

/// Home Assistant's `online` 600 times at 40 a second on a site of some 250 configs, with a
/// 1 MB spool: no reading is lost (once every `online` re-announced everything into the same
/// outbox and the bound pushed readings out), and the spool's disk sees almost nothing.
/// Run from `burn_in` (it starts with the other long runs).
pub(crate) async fn a_flood_of_home_assistant_births_costs_no_reading_and_no_disk() {
    let broker = Broker::start();
    let extra = format!("[homeassistant]\ndiscovery = true\n{}", ghost_bus(190));
    let (_plant, gw, sub) = rig("rf-ha-flood", &broker, &extra).await;
    let ha = Subscriber::start(broker.port, "homeassistant/+/test/+/config").await;
    // The first announcement, complete (the retained configs arrive as they are published).
    let mut configs = 0;
    for _ in 0..40 {
        tokio::time::sleep(Duration::from_millis(500)).await;
        let now = ha.all().len();
        if now == configs && now > 0 {
            break;
        }
        configs = now;
    }
    ha.clear();
    assert!(configs >= 250, "a site of {configs} configs");
    let written = disk_writes(gw.pid());
    let started = Instant::now();
    for i in 0..600u32 {
        ha.client
            .publish("homeassistant/status", QoS::AtMostOnce, false, "online")
            .await
            .unwrap();
        let next = started + Duration::from_millis(25 * u64::from(i + 1));
        tokio::time::sleep(next.saturating_duration_since(Instant::now())).await;
    }
    let flood_writes = disk_writes(gw.pid()) - written;
    tokio::time::sleep(Duration::from_secs(2)).await;
    let announced = ha.all().len();
    println!(
        "HA flood: {configs} configs, {announced} config messages in all, {flood_writes} bytes written"
    );
    assert!(
        announced <= configs * 6,
        "re-announcements coalesced: {announced} messages for {configs} configs"
    );
    assert!(flood_writes < 2 << 20, "{flood_writes} bytes written");
    assert_every_pulse_counted(&sub);
}

/// Thirty thousand `clear_all` to a device that does not exist, in a burst: every refusal is a
/// result, but results are chatter and the readings of the burst all arrive.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_burst_of_commands_to_an_unknown_device_costs_no_reading() {
    let broker = Broker::start();
    let (_plant, _gw, sub) = rig("rf-cmd-flood", &broker, "").await;
    let results = Subscriber::start(broker.port, "pulsegate/test/nosuch/cmd/result").await;
    for _ in 0..30_000 {
        results
            .client
            .publish(
                "pulsegate/test/nosuch/cmd",
                QoS::AtMostOnce,
                false,
                r#"{"op":"clear_all"}"#,
            )
            .await
            .unwrap();
    }
    // Polls every 200 ms: readings go on through the burst (a loaded machine may take a while
    // over 30,000 commands; what is checked is that none is lost and they keep coming).
    for d in ["m1", "m2", "m3"] {
        let topic = format!("pulsegate/test/{d}/enc0");
        sub.wait_more_than(&topic, 10, Duration::from_secs(30))
            .await;
    }
    println!("command burst: {} results", results.all().len());
    assert!(!results.all().is_empty(), "refusals answered");
    assert_every_pulse_counted(&sub);
}

/// The broker stops answering (SIGSTOP), state saves pass, the gateway is killed, the broker
/// comes back and the gateway restarts: a consumer following `after_seq` sums exactly the
/// pulses counted. Readings the saves covered were in memory only, once.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_crash_after_a_broker_stall_loses_no_pulse_for_a_consumer() {
    let broker = Broker::start();
    let plant = plant(KILLED_ENCODER).await;
    let dir = temp_dir("rf-stall-crash");
    let topic = "pulsegate/test/m/a0";
    let sub = Subscriber::start(broker.port, topic).await;
    let devices = [("line1", "m", 1, "yl67", "50ms")];
    let config = write_config(
        &dir,
        &gateway_toml(&plant, broker.port, &dir, &devices, "").replacen(
            "[mqtt]\n",
            "[mqtt]\nkeep_alive = \"30s\"\n",
            1,
        ),
    );
    let gw = Gateway::start(&config);
    sub.wait_more_than(topic, 5, Duration::from_secs(10)).await;
    let pid = broker.pid().to_string();
    let signal = |sig: &str| {
        std::process::Command::new("kill")
            .args([sig, &pid])
            .status()
            .unwrap()
    };
    signal("-STOP");
    // Saves every 500 ms: several pass while the broker takes nothing.
    saves_pass(&dir.join("bus-line1.json"), 4).await;
    gw.kill();
    signal("-CONT");
    let gw = Gateway::start(&config);
    let (all, generated) = stop_and_collect(&plant, &sub, gw, topic).await;
    let first_count = all[0]["count"].as_i64().unwrap();
    assert!(
        all.iter().any(|r| r["after_seq"].is_i64()),
        "the second run counts from the saved seq"
    );
    assert_eq!(consume(&all), generated - first_count, "summed deltas");
}

/// The stall and crash of the test above, on a gateway whose only output is Sparkplug B: the
/// SCADA host's totals (what it historises) run on to exactly the pulses the module counted,
/// never backwards, across the stall, the crash and the restart.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_crash_after_a_broker_stall_loses_no_pulse_for_a_sparkplug_host() {
    use crate::sparkplug::{Host, no_errors, of_type};
    let broker = Broker::start();
    let host = Host::start(broker.port, false);
    let plant = plant(KILLED_ENCODER).await;
    let dir = temp_dir("rf-stall-crash-sparkplug");
    let devices = [("line1", "m", 1, "yl67", "50ms")];
    let extra = "[outputs.scada]\nkind = \"sparkplug\"\n[sparkplug]\ngroup_id = \"plant\"\n";
    let config = write_config(
        &dir,
        &gateway_toml(&plant, broker.port, &dir, &devices, extra),
    );
    let gw = Gateway::start(&config);
    host.wait(Duration::from_secs(15), "data", |l| {
        of_type(l, "DDATA").count() >= 10
    })
    .await;
    let pid = broker.pid().to_string();
    let signal = |sig: &str| {
        std::process::Command::new("kill")
            .args([sig, &pid])
            .status()
            .unwrap()
    };
    signal("-STOP");
    saves_pass(&dir.join("bus-line1.json"), 4).await;
    gw.kill();
    signal("-CONT");
    let gw = Gateway::start(&config);
    let generated = stop_counting_and_gateway(&plant, gw, Duration::from_secs(2)).await;
    let lines = host.lines();
    no_errors(&lines);
    // A host files values by their timestamps: what the restart sent again of the crashed
    // run's (at least once) lands on the same time with the same value.
    let mut by_time: BTreeMap<u64, i64> = BTreeMap::new();
    for m in of_type(&lines, "DDATA")
        .flat_map(|d| d["metrics"].as_array().unwrap().clone())
        .filter(|m| m["name"] == "a0/Total")
    {
        let (t, v) = (
            m["timestamp"].as_u64().unwrap(),
            m["value"].as_i64().unwrap(),
        );
        let earlier = by_time.insert(t, v);
        assert!(
            earlier.is_none_or(|e| e == v),
            "two totals at {t}: {earlier:?} and {v}"
        );
    }
    let totals: Vec<i64> = by_time.into_values().collect();
    assert!(totals.len() > 20, "{} totals", totals.len());
    assert!(
        totals.windows(2).all(|w| w[1] >= w[0]),
        "a total never goes backwards in time: {totals:?}"
    );
    let counts: Vec<i64> = of_type(&lines, "DDATA")
        .flat_map(|d| d["metrics"].as_array().unwrap().clone())
        .filter(|m| m["name"] == "a0/Count")
        .map(|m| m["value"].as_i64().unwrap())
        .collect();
    assert_eq!(
        totals.last().unwrap() - totals[0],
        generated - counts[0],
        "the host's totals moved by exactly the pulses counted"
    );
}

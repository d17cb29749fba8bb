//! The gateway reading M-Bus meters of the simulator, against a real Mosquitto: three meters on
//! one TCP segment (two at primary address 0, told apart by their secondary addresses) and one
//! on a serial segment at 2400 8E1 over a pseudo-terminal. Registers are counted exactly
//! through an 8-digit BCD roll-over and a meter replaced (summed deltas = the simulator's own
//! count), values are published in their units, and a meter answering garbage or nothing goes
//! offline while the others keep their rate.

use std::path::Path;
use std::time::{Duration, Instant};

use pulsegate::mbus::sim::gateway::MeterLine;
use pulsegate::sim::Plant;
use pulsegate::sim::gateway::GatewayToml;

use crate::support::*;

/// The gateway's config for `meters` of `plant`: M-Bus buses only, with `bus` keys on each.
pub fn meters_toml(
    plant: &Plant,
    broker_port: u16,
    state_dir: &Path,
    meters: &[MeterLine<'_>],
    bus: &str,
) -> String {
    let t = GatewayToml {
        id: "test",
        state_dir,
        gateway: "state_flush = \"500ms\"\n",
        mqtt_host: "127.0.0.1",
        mqtt_port: Some(broker_port),
        mqtt: "",
        serial: "",
        tcp: "",
    };
    t.render(plant, &[]) + &t.meters(plant, meters, bus)
}

const PLANT: &str = r#"
[mbus.field]
listen = "127.0.0.1:0"
[mbus.field.meters.heat_a]
id = 12345678
manufacturer = "KAM"
medium = 4
address = 0
registers = [{ quantity = "energy_wh", width = "bcd8", start = 99998800, rate = 200.0 }]
gauges = { power_w = 2300, flow_temperature_centi = 6025 }
[mbus.field.meters.heat_b]
id = 19876543
manufacturer = "KAM"
medium = 4
address = 0
registers = [{ quantity = "volume_litre", width = "int32", start = 5000, rate = 50.0 }]
[mbus.field.meters.water]
id = 55500001
address = 5
registers = [{ quantity = "volume_litre", width = "bcd8", start = 1000, rate = 20.0 }]
[mbus.cellar]
baud = 2400
[mbus.cellar.meters.gas]
id = 77700001
medium = 3
address = 7
registers = [{ quantity = "volume_litre", width = "bcd8", start = 300, rate = 10.0 }]
"#;

const METERS: &[MeterLine<'static>] = &[
    ("field", "heat_a", "heat_a", "500ms"),
    ("field", "heat_b", "heat_b", "500ms"),
    ("field", "water", "water", "500ms"),
    ("cellar", "gas", "gas", "1s"),
];

/// The simulator's own count of a meter's first register since time 0 (no roll-over).
fn counted(plant: &Plant, segment: &str, meter: &str) -> u64 {
    let now = plant.now();
    plant
        .segment(segment)
        .unwrap()
        .with_meter(meter, |m| m.registers[0].counted(now))
        .unwrap()
}

/// Stops (rate 0) or restarts a meter's first register.
fn set_rate(plant: &Plant, segment: &str, meter: &str, rate: f64) {
    let now = plant.now();
    plant
        .segment(segment)
        .unwrap()
        .with_meter(meter, |m| m.registers[0].set_rate(now, rate))
        .unwrap();
}

/// Waits until a reading of `topic` arrived after `since`.
async fn fresh(sub: &Subscriber, topic: &str, since: Instant) -> serde_json::Value {
    sub.wait_for(topic, Duration::from_secs(10), |m| m.at > since)
        .await
        .unwrap_or_else(|| panic!("no fresh reading on {topic}"))
        .json()
}

/// The text of a top-level value in a JSON payload, exactly as sent.
fn raw<'a>(payload: &'a str, key: &str) -> Option<&'a str> {
    let start = payload.find(&format!("\"{key}\":"))? + key.len() + 3;
    let rest = &payload[start..];
    let end = rest.find([',', '}']).unwrap_or(rest.len());
    Some(&rest[..end])
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn meters_are_counted_exactly_through_a_roll_over_and_a_replacement() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("mbus-count");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = meters_toml(&plant, broker.port, &dir, METERS, "");
    assert!(
        text.contains("id = \"12345678\"") && text.contains("address = 5"),
        "{text}"
    );
    let _gw = Gateway::start(&write_config(&dir, &text));

    // Every meter answers: the two at address 0 by their ids, the gas meter over the pty.
    for topic in [
        "pulsegate/test/heat_a/energy",
        "pulsegate/test/heat_b/volume",
        "pulsegate/test/water/volume",
        "pulsegate/test/gas/volume",
    ] {
        sub.expect_any(topic, Duration::from_secs(10)).await;
    }
    let heat = "pulsegate/test/heat_a/energy";
    let first = sub.on(heat)[0].json();

    // heat_a's 8-digit BCD register rolls over at 10^8 within seconds.
    let rolled = sub
        .wait_for(heat, Duration::from_secs(20), |m| {
            m.json()["event"] == "rollover"
        })
        .await;
    assert!(
        rolled.is_some(),
        "no roll-over seen: {:?}",
        sub.on(heat).last().map(|m| &m.payload)
    );

    // The water meter is replaced: stopped and read once more (the gateway cannot know what
    // the old one counts after its last read), swapped for a new one at 0 that starts
    // counting once the gateway has read it (what a new meter holds at its first read is no
    // delta: the core counts on from there).
    let water = "pulsegate/test/water/volume";
    set_rate(&plant, "field", "water", 0.0);
    let stopped = counted(&plant, "field", "water");
    let mark = Instant::now();
    fresh(&sub, water, mark).await;
    fresh(&sub, water, Instant::now()).await;
    let now = plant.now();
    plant
        .segment("field")
        .unwrap()
        .with_meter("water", |m| m.replace(now, 55500099))
        .unwrap();
    let reset = sub
        .wait_for(water, Duration::from_secs(10), |m| {
            m.json()["event"] == "reset"
        })
        .await
        .expect("the replaced meter is a reset");
    assert_eq!(reset.json()["delta"], 0, "no delta across a replacement");
    set_rate(&plant, "field", "water", 20.0);
    let from = reset.json()["total"].as_i64().unwrap();
    sub.wait_for(water, Duration::from_secs(10), |m| {
        m.json()["total"].as_i64() > Some(from)
    })
    .await
    .expect("the new meter counts on");

    // Everything stops; the last readings' totals are the simulator's own counts.
    for (seg, meter) in [
        ("field", "heat_a"),
        ("field", "heat_b"),
        ("field", "water"),
        ("cellar", "gas"),
    ] {
        set_rate(&plant, seg, meter, 0.0);
    }
    let end = Instant::now();
    tokio::time::sleep(Duration::from_millis(300)).await;
    for (seg, meter, channel) in [
        ("field", "heat_a", "energy"),
        ("field", "heat_b", "volume"),
        ("field", "water", "volume"),
        ("cellar", "gas", "volume"),
    ] {
        let topic = format!("pulsegate/test/{meter}/{channel}");
        // A reading published after the stop may have been read just before it; the next one
        // is a poll period later, so surely read after it.
        fresh(&sub, &topic, end).await;
        fresh(&sub, &topic, Instant::now()).await;
        let all = readings(&sub, &topic);
        let deltas: Vec<i64> = all.iter().map(|r| r["delta"].as_i64().unwrap()).collect();
        assert!(
            deltas.iter().all(|d| *d >= 0),
            "{topic}: a negative delta in {deltas:?}"
        );
        let summed: i64 = deltas.iter().sum();
        assert_eq!(
            summed,
            all.last().unwrap()["total"].as_i64().unwrap(),
            "{topic}"
        );
        let first = all[0]["count"].as_i64().unwrap();
        let own = match meter {
            // The old meter's count up to its stop, then the new meter's from 0.
            "water" => (stopped as i64 - first) + counted(&plant, seg, meter) as i64,
            _ => counted(&plant, seg, meter) as i64 - first,
        };
        assert_eq!(
            summed, own,
            "{topic}: summed deltas against the simulator's count"
        );
        assert!(summed > 0, "{topic} counted nothing");
    }
    assert!(first["count"].as_i64().unwrap() >= 99_998_800);

    // Values with their units, exact: litres as m³, the flow temperature in 0.01 °C steps.
    let volume = sub.on(water).last().unwrap().payload.clone();
    let total = serde_json::from_str::<serde_json::Value>(&volume).unwrap()["total"]
        .as_i64()
        .unwrap();
    let want = format!("{}.{:03}", total / 1000, total % 1000);
    let want = want.trim_end_matches('0').trim_end_matches('.');
    assert_eq!(raw(&volume, "value"), Some(want), "{volume}");
    assert_eq!(raw(&volume, "unit"), Some("\"m³\""), "{volume}");
    let temp = sub.on("pulsegate/test/heat_a/flow_temperature");
    let temp = &temp
        .last()
        .expect("the flow temperature is published")
        .payload;
    assert_eq!(raw(temp, "value"), Some("60.25"), "{temp}");
    assert_eq!(raw(temp, "unit"), Some("\"°C\""), "{temp}");
    let power = sub.on("pulsegate/test/heat_a/power");
    assert_eq!(
        raw(&power.last().expect("power").payload, "value"),
        Some("2300")
    );
    let energy = sub.on(heat).last().unwrap().payload.clone();
    assert_eq!(raw(&energy, "unit"), Some("\"Wh\""), "{energy}");
}

const FAULTS: &str = r#"
[mbus.field]
listen = "127.0.0.1:0"
[mbus.field.meters.good]
id = 11110001
address = 1
registers = [{ quantity = "volume_litre", start = 0, rate = 5.0 }]
[mbus.field.meters.noisy]
id = 11110002
address = 2
registers = [{ quantity = "volume_litre", start = 0, rate = 5.0 }]
[mbus.field.meters.mute]
id = 11110003
address = 3
registers = [{ quantity = "volume_litre", start = 0, rate = 5.0 }]
"#;

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_meter_answering_garbage_or_nothing_goes_offline_and_the_others_keep_their_rate() {
    let broker = Broker::start();
    let plant = plant(FAULTS).await;
    let dir = temp_dir("mbus-faults");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let meters: &[MeterLine<'_>] = &[
        ("field", "good", "good", "300ms"),
        ("field", "noisy", "noisy", "300ms"),
        ("field", "mute", "mute", "300ms"),
    ];
    let keys = "timeout = \"150ms\"\nbackoff_min = \"1s\"\nbackoff_max = \"4s\"\n";
    let text = meters_toml(&plant, broker.port, &dir, meters, keys);
    let _gw = Gateway::start(&write_config(&dir, &text));
    for d in ["good", "noisy", "mute"] {
        sub.wait_for(
            &format!("pulsegate/test/{d}/status"),
            Duration::from_secs(10),
            |m| m.payload == "online",
        )
        .await
        .unwrap_or_else(|| panic!("{d} never online"));
    }
    let seg = plant.segment("field").unwrap();
    seg.with_meter("noisy", |m| {
        m.behaviour = pulsegate::mbus::sim::Behaviour::Garbage
    });
    seg.with_meter("mute", |m| {
        m.behaviour = pulsegate::mbus::sim::Behaviour::Silent
    });
    let broke = Instant::now();
    for d in ["noisy", "mute"] {
        let off = sub
            .wait_for(
                &format!("pulsegate/test/{d}/status"),
                Duration::from_secs(10),
                |m| m.payload == "offline" && m.at > broke,
            )
            .await;
        assert!(off.is_some(), "{d} did not go offline");
    }
    // While the two are away (probed with backoff), the good meter keeps its 300 ms rate.
    let watch = Instant::now();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let good: Vec<Instant> = sub
        .on("pulsegate/test/good/volume")
        .iter()
        .map(|m| m.at)
        .filter(|at| *at > watch)
        .collect();
    assert!(
        good.len() >= 10,
        "the good meter slowed down: {} readings in 4 s",
        good.len()
    );
    let longest = good.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(
        longest < Duration::from_millis(900),
        "a gap of {longest:?} between readings"
    );
    // Repaired, they come back.
    seg.with_meter("noisy", |m| {
        m.behaviour = pulsegate::mbus::sim::Behaviour::Normal
    });
    seg.with_meter("mute", |m| {
        m.behaviour = pulsegate::mbus::sim::Behaviour::Normal
    });
    let fixed = Instant::now();
    for d in ["noisy", "mute"] {
        let on = sub
            .wait_for(
                &format!("pulsegate/test/{d}/status"),
                Duration::from_secs(10),
                |m| m.payload == "online" && m.at > fixed,
            )
            .await;
        assert!(on.is_some(), "{d} did not come back");
    }
}

/// Runs `pulsegate ARGS` to the end: (stdout, stderr, success).
async fn pg(args: &[&str]) -> (String, String, bool) {
    let o = tokio::process::Command::new(bin())
        .args(args)
        .env("RUST_LOG", "warn")
        .output()
        .await
        .expect("run pulsegate");
    (
        String::from_utf8_lossy(&o.stdout).into(),
        String::from_utf8_lossy(&o.stderr).into(),
        o.status.success(),
    )
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_secondary_scan_finds_every_meter_through_collisions_and_its_toml_passes_check() {
    let plant = plant(PLANT).await;
    let host = match &plant.segment("field").unwrap().endpoint {
        pulsegate::sim::Endpoint::Tcp(a) => a.to_string(),
        other => panic!("{other:?}"),
    };
    let scan = ["scan", "--protocol", "mbus", "--host", &host, "--secondary"];
    let (out, err, ok) = pg(&[&scan[..], &["--timeout", "100ms", "--json"]].concat()).await;
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    let ids: Vec<&str> = v["found"]
        .as_array()
        .unwrap()
        .iter()
        .map(|m| m["id"].as_str().unwrap())
        .collect();
    assert_eq!(ids, ["12345678", "19876543", "55500001"], "{out}");
    assert!(
        v["collisions"].as_u64().unwrap() >= 1,
        "ids starting with 1 collide: {out}"
    );
    let kam = &v["found"][0];
    assert_eq!(
        (
            kam["manufacturer"].as_str(),
            kam["version"].as_u64(),
            kam["medium"].as_u64()
        ),
        (Some("KAM"), Some(1), Some(4))
    );
    assert_eq!(
        (kam["address"].as_u64(), v["found"][2]["address"].as_u64()),
        (Some(0), Some(5))
    );

    // The table names them, and --toml gives a config `pulsegate check` accepts.
    let (table, _, _) = pg(&[&scan[..], &["--timeout", "100ms"]].concat()).await;
    assert!(
        table.contains("12345678") && table.contains("KAM") && table.contains("3 meter(s)"),
        "{table}"
    );
    let (toml, err, ok) = pg(&[&scan[..], &["--timeout", "100ms", "--toml"]].concat()).await;
    assert!(ok, "{err}");
    assert!(
        toml.contains("id = \"12345678\"") && toml.contains("address = 5"),
        "{toml}"
    );
    let dir = temp_dir("mbus-scan-toml");
    let file = write_config(
        &dir,
        &toml.replace("# id = \"<host name>\"", "id = \"edge\""),
    );
    let (out, err, ok) = pg(&["check", "--config", file.to_str().unwrap()]).await;
    assert!(ok, "check refused the scan's config: {out}{err}\n{toml}");

    // The serial meter, read at 2400 8E1 over the pty.
    let port = match &plant.segment("cellar").unwrap().endpoint {
        pulsegate::sim::Endpoint::Serial(p) => p.display().to_string(),
        other => panic!("{other:?}"),
    };
    let read = [
        "read",
        "--protocol",
        "mbus",
        "--port",
        &port,
        "--address",
        "7",
        "--json",
    ];
    let (out, err, ok) = pg(&read).await;
    assert!(ok, "{err}");
    let v: serde_json::Value = serde_json::from_str(&out).unwrap();
    for key in [
        "id",
        "manufacturer",
        "version",
        "medium",
        "access",
        "status",
        "records",
    ] {
        assert!(v.get(key).is_some(), "no {key} in {out}");
    }
    assert_eq!(
        (v["id"].as_str(), v["medium"].as_u64()),
        (Some("77700001"), Some(3))
    );
    let volume = &v["records"][0];
    for key in [
        "index", "quantity", "function", "storage", "tariff", "subunit", "unit", "value",
    ] {
        assert!(volume.get(key).is_some(), "no {key} in {volume}");
    }
    assert_eq!(
        (volume["quantity"].as_str(), volume["unit"].as_str()),
        (Some("volume"), Some("m³"))
    );
    assert!(volume["value"].as_f64().unwrap() >= 0.3, "{volume}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_over_mqtt_finds_a_meter_on_an_mbus_bus_with_progress() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("mbus-service-scan");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let meters: &[MeterLine<'_>] = &[("field", "heat_a", "heat_a", "1s")];
    let text = meters_toml(&plant, broker.port, &dir, meters, "timeout = \"100ms\"\n");
    let _gw = Gateway::start(&write_config(&dir, &text));
    sub.expect_any("pulsegate/test/heat_a/energy", Duration::from_secs(10))
        .await;
    sub.send(
        "pulsegate/test/bus/field/scan",
        r#"{"units":"1-10","id":"s1"}"#,
    )
    .await;
    let result = sub
        .wait_for(
            "pulsegate/test/bus/field/scan/result",
            Duration::from_secs(30),
            |_| true,
        )
        .await
        .expect("a scan result");
    let v = result.json();
    let found = v["found"].as_array().expect("found");
    assert_eq!(found.len(), 1, "{v}");
    assert_eq!(
        (found[0]["unit"].as_u64(), found[0]["meter"]["id"].as_str()),
        (Some(5), Some("55500001"))
    );
    let progress = sub.on("pulsegate/test/bus/field/scan/progress");
    assert_eq!(progress.len(), 1, "one meter found, one progress message");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_meter_register_is_discovered_counted_in_intervals_and_born_in_sparkplug() {
    use crate::dashboards::valid_config;
    use crate::sparkplug::{Host, metric, no_errors, of_type};
    let broker = Broker::start();
    let host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("mbus-dashboards");
    let ha = Subscriber::start(broker.port, "homeassistant/#").await;
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let meters: &[MeterLine<'_>] = &[
        ("field", "heat_a", "heat_a", "500ms"),
        ("field", "water", "water", "500ms"),
    ];
    let text = meters_toml(&plant, broker.port, &dir, meters, "")
        .replacen("[gateway]\n", "[gateway]\nintervals = [\"2s\"]\n", 1)
        .replacen(
            "[mqtt]\n",
            "[mqtt]\nformat = [\"json\", \"sparkplug\"]\n",
            1,
        )
        + "[homeassistant]\ndiscovery = true\n[sparkplug]\ngroup_id = \"plant\"\n";
    let _gw = Gateway::start(&write_config(&dir, &text));

    // Intervals of a meter register: records whose value is the delta in the register's unit.
    let interval = "pulsegate/test/heat_a/energy/interval/2s";
    let record = sub
        .wait_for(interval, Duration::from_secs(15), |m| {
            m.json()["delta"].as_i64() > Some(0)
        })
        .await
        .expect("an interval record of the energy register");
    let r = record.json();
    assert_eq!(r["value"].as_i64(), r["delta"].as_i64(), "1 Wh steps: {r}");
    assert_eq!(
        r["total_end"].as_i64().unwrap() - r["total_start"].as_i64().unwrap(),
        r["delta"].as_i64().unwrap()
    );

    // Home Assistant: the register a total_increasing energy sensor, the gauges measurements
    // with their classes, every config valid, no clear button for a meter.
    let prefix = "homeassistant/sensor/test/field_id12345678";
    let want = [
        (
            format!("{prefix}_energy_total/config"),
            "energy",
            "total_increasing",
            "Wh",
        ),
        (
            format!("{prefix}_power/config"),
            "power",
            "measurement",
            "W",
        ),
        (
            format!("{prefix}_flow_temperature/config"),
            "temperature",
            "measurement",
            "°C",
        ),
        (
            "homeassistant/sensor/test/field_a5_volume_total/config".to_string(),
            "water",
            "total_increasing",
            "m³",
        ),
    ];
    for (topic, class, state_class, unit) in &want {
        let m = ha
            .wait_for(topic, Duration::from_secs(10), |m| !m.payload.is_empty())
            .await
            .unwrap_or_else(|| panic!("no config {topic}"));
        let v = valid_config(topic, &m.payload);
        assert_eq!(
            (
                v["device_class"].as_str(),
                v["state_class"].as_str(),
                v["unit_of_measurement"].as_str()
            ),
            (Some(*class), Some(*state_class), Some(*unit)),
            "{topic}: {v}"
        );
        assert_eq!(v["availability_mode"], "all", "{topic}");
        assert_eq!(v["device"]["via_device"], "pulsegate_test", "{topic}");
    }
    tokio::time::sleep(Duration::from_secs(2)).await;
    for m in ha
        .all()
        .iter()
        .filter(|m| !m.payload.is_empty() && m.topic.ends_with("/config"))
    {
        if m.topic.contains("field_") {
            valid_config(&m.topic, &m.payload);
            assert!(
                !m.topic.contains("/button/"),
                "a meter cannot be cleared: {}",
                m.topic
            );
        }
    }
    let reading = ha.on(&format!("{prefix}_energy_reading/config"));
    assert!(!reading.is_empty(), "the meter reading sensor");
    let totals: Vec<i64> = readings(&sub, "pulsegate/test/heat_a/energy")
        .iter()
        .filter_map(|r| r["total"].as_i64())
        .collect();
    assert!(totals.windows(2).all(|w| w[0] <= w[1]), "{totals:?}");

    // Sparkplug: the register's metrics with its unit, the gauges as values with theirs.
    host.wait(
        Duration::from_secs(15),
        "heat_a born with its records",
        |l| {
            of_type(l, "DBIRTH")
                .any(|b| b["device"] == "heat_a" && metric(b, "power/Value").is_some())
        },
    )
    .await;
    host.wait(Duration::from_secs(10), "heat_a's data", |l| {
        of_type(l, "DDATA").any(|d| d["device"] == "heat_a" && metric(d, "energy/Total").is_some())
    })
    .await;
    let lines = host.lines();
    no_errors(&lines);
    let birth = of_type(&lines, "DBIRTH")
        .filter(|b| b["device"] == "heat_a")
        .last()
        .unwrap();
    assert_eq!(
        metric(birth, "energy/Value").unwrap()["properties"]["engUnit"],
        "Wh"
    );
    assert_eq!(metric(birth, "energy/Total").unwrap()["datatype"], "UINT64");
    assert_eq!(
        metric(birth, "power/Value").unwrap()["properties"]["engUnit"],
        "W"
    );
    assert!(
        metric(birth, "energy/Clear").is_none(),
        "a meter register is not writable"
    );
}

/// A meter that answers has a last answer and a latency on the status API (they were never set
/// for M-Bus: the page said "last answer never" for a meter answering every 300 ms).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_meter_that_answers_shows_its_last_answer_and_latency() {
    let broker = Broker::start();
    let plant = plant(FAULTS).await;
    let dir = temp_dir("mbus-last-answer");
    let http = free_port();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let meters: &[MeterLine<'_>] = &[("field", "good", "good", "300ms")];
    let text = meters_toml(&plant, broker.port, &dir, meters, "timeout = \"150ms\"\n")
        + &format!("[metrics]\nlisten = \"127.0.0.1:{http}\"\n");
    let _gw = Gateway::start(&write_config(&dir, &text));
    sub.wait_for("pulsegate/test/good/status", Duration::from_secs(10), |m| {
        m.payload == "online"
    })
    .await
    .expect("online");
    // The status says the meter's last answer, within a few polls.
    let good = || {
        let (code, body) = crate::metrics::http_get(http, "/api/v1/status");
        assert_eq!(code, 200, "{body}");
        let status: serde_json::Value = serde_json::from_str(&body).unwrap();
        let devices = status["devices"].as_array().unwrap();
        let good = devices.iter().find(|d| d["name"] == "good");
        good.unwrap_or_else(|| panic!("{status}")).clone()
    };
    until(
        Duration::from_secs(10),
        "the meter's last answer",
        || good()["last_answer_ms"].is_u64(),
        || good().to_string(),
    )
    .await;
}

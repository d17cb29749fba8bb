//! Outputs that stand alone: Sparkplug B to one broker, JSON with Home Assistant discovery to
//! another, each with its own connection, will, store and hold; a Sparkplug-only gateway that
//! still answers every command. Real Mosquittos, the simulated modules, and the pysparkplug host
//! of tests/sparkplug_host.py.

use std::path::{Path, PathBuf};
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;
use serde_json::{Value, json};

use crate::metrics::{http_get, sample, scrape_until};
use crate::sparkplug::{Host, assert_seq_unbroken, metric, no_errors, of_type};
use crate::support::*;

/// Two modules counting on line1, as the Sparkplug tests have them.
use crate::sparkplug::{DEVICES, PLANT};

/// JSON with Home Assistant discovery to the `[mqtt]` broker (`json_port`), Sparkplug to the
/// broker on `scada_port`, plus `extra`.
fn two_brokers(plant: &Plant, json_port: u16, scada_port: u16, dir: &Path, extra: &str) -> PathBuf {
    let outputs = format!(
        "[outputs.local]\nkind = \"homeassistant\"\n\
         [outputs.scada]\nkind = \"sparkplug\"\nport = {scada_port}\n\
         [sparkplug]\ngroup_id = \"plant\"\n{extra}"
    );
    write_config(
        dir,
        &gateway_toml(plant, json_port, dir, &DEVICES, &outputs),
    )
}

/// The JSON readings of `topic`, checked: seq without a gap, deltas that add up.
fn assert_json_exact(sub: &Subscriber, topic: &str) -> Vec<Value> {
    let all = readings(sub, topic);
    assert!(all.len() > 5, "{topic}: {} readings", all.len());
    for w in all.windows(2) {
        let (a, b) = (&w[0], &w[1]);
        assert_eq!(
            b["seq"].as_i64(),
            a["seq"].as_i64().map(|s| s + 1),
            "{topic}: {a} then {b}"
        );
        let moved = b["total"].as_i64().unwrap() - a["total"].as_i64().unwrap();
        assert_eq!(b["delta"].as_i64(), Some(moved), "{topic}: {a} then {b}");
    }
    all
}

/// Every Sparkplug `<channel>/Total` of `device` in arrival order, checked against its `Delta`:
/// each total is the one before plus the delta (historical and live alike). The totals.
fn assert_sparkplug_exact(lines: &[Value], device: &str, channel: &str) -> Vec<i64> {
    let (total, delta) = (format!("{channel}/Total"), format!("{channel}/Delta"));
    let mut totals: Vec<i64> = Vec::new();
    for l in of_type(lines, "DDATA").filter(|l| l["device"] == device) {
        let ms = l["metrics"].as_array().unwrap();
        let totals_here = ms.iter().filter(|m| m["name"] == *total);
        let deltas_here = ms.iter().filter(|m| m["name"] == *delta);
        for (t, d) in totals_here.zip(deltas_here) {
            let (t, d) = (t["value"].as_i64().unwrap(), d["value"].as_i64().unwrap());
            if let Some(last) = totals.last() {
                assert_eq!(
                    t,
                    last + d,
                    "{device}/{channel}: {last} then {t} with delta {d}"
                );
            }
            totals.push(t);
        }
    }
    totals
}

/// SIGKILL: each broker publishes the will of the output that connected to it, the gateway's
/// `offline` on the JSON broker and the NDEATH on the SCADA broker; both outputs published
/// before, each on its own broker only.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn each_broker_gets_its_own_output_and_its_own_will() {
    let (local, scada) = (Broker::start(), Broker::start());
    let host = Host::start(scada.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("outputs-wills");
    let sub = Subscriber::start(local.port, "#").await;
    let scada_sub = Subscriber::start(scada.port, "pulsegate/#").await;
    let config = two_brokers(&plant, local.port, scada.port, &dir, "");
    // `check` says where readings go, and which connection carries the gateway's voice.
    let checked = std::process::Command::new(bin())
        .args(["check", "--config"])
        .arg(&config)
        .output()
        .unwrap();
    let said = String::from_utf8_lossy(&checked.stdout);
    let local_line = format!(
        "output local (homeassistant): 127.0.0.1:{} as pulsegate-test-local, with the gateway's status and commands",
        local.port
    );
    let scada_line = format!(
        "output scada (sparkplug): 127.0.0.1:{} as pulsegate-test-scada",
        scada.port
    );
    assert!(
        said.contains(&local_line) && said.contains(&scada_line),
        "{said}"
    );
    let gw = Gateway::start(&config);
    host.wait(Duration::from_secs(15), "both devices born", |l| {
        of_type(l, "DBIRTH").count() >= 2 && of_type(l, "DDATA").count() >= 5
    })
    .await;
    sub.expect_any("pulsegate/test/wj/a0", Duration::from_secs(10))
        .await;
    sub.wait_for("pulsegate/test/status", Duration::from_secs(5), |m| {
        m.payload == "online"
    })
    .await
    .expect("the gateway online on the JSON broker");
    assert!(
        sub.all()
            .iter()
            .any(|m| m.topic.starts_with("homeassistant/") && m.topic.ends_with("/config")),
        "discovery on the JSON broker"
    );
    assert!(
        sub.all().iter().all(|m| !m.topic.starts_with("spBv1.0/")),
        "no Sparkplug on the JSON broker"
    );
    assert!(
        scada_sub.all().is_empty(),
        "no JSON topic on the SCADA broker"
    );
    gw.kill();
    sub.wait_for("pulsegate/test/status", Duration::from_secs(10), |m| {
        m.payload == "offline"
    })
    .await
    .expect("the JSON broker published the gateway's will");
    host.wait(Duration::from_secs(10), "the NDEATH", |l| {
        of_type(l, "NDEATH").count() >= 1
    })
    .await;
    no_errors(&host.lines());
}

/// The SCADA broker is away while forty JSON readings of `wj/a0` arrive (about 10 s, ten
/// reconnect attempts a second apart): JSON readings keep flowing on the other broker with no
/// gap and no pause; when it returns, the Sparkplug output sends what it kept, flagged
/// historical, and its totals run on without a pulse missing. Run from `burn_in` (it starts with
/// the other long runs); a minute's outage of an output runs on paused time in
/// `src/publish/mqtt/paused_tests.rs`.
pub(crate) async fn the_scada_broker_away_costs_json_nothing_and_sparkplug_no_pulse() {
    let local = Broker::start();
    let scada_port = free_port();
    let scada_dir = temp_dir("outputs-scada-broker");
    let mut scada = Broker::start_persistent(scada_port, &scada_dir);
    let host = Host::start(scada_port, true);
    let plant = plant(PLANT).await;
    let dir = temp_dir("outputs-outage");
    let topic = "pulsegate/test/wj/a0";
    let sub = Subscriber::start(local.port, topic).await;
    let gw = Gateway::start(&two_brokers(&plant, local.port, scada_port, &dir, ""));
    host.wait(Duration::from_secs(15), "data", |l| {
        of_type(l, "DDATA").count() >= 10
    })
    .await;
    scada.terminate();
    let away = Instant::now();
    let during = || -> Vec<Instant> {
        let on = sub.on(topic);
        on.iter().map(|m| m.at).filter(|t| *t > away).collect()
    };
    until(
        Duration::from_secs(60),
        "JSON readings during the outage",
        || during().len() >= 40,
        || gw.log_text(),
    )
    .await;
    let during = during();
    let outage = away.elapsed();
    // Polled every 100 ms (batched up to 250 ms): a pause of a second would be the outage's.
    let longest = during.windows(2).map(|w| w[1] - w[0]).max().unwrap();
    assert!(
        during.len() as f64 > 3.5 * outage.as_secs_f64(),
        "{} JSON readings in {outage:?}",
        during.len()
    );
    assert!(longest < Duration::from_secs(1), "JSON paused {longest:?}");
    let _scada = Broker::start_persistent(scada_port, &scada_dir);
    host.wait(
        Duration::from_secs(30),
        "the outage's data, then live data",
        |l| {
            let historical = of_type(l, "DDATA")
                .filter(|d| d["device"] == "wj")
                .filter(|d| metric(d, "a0/Total").is_some_and(|m| m["is_historical"] == true))
                .count();
            historical > 15
                && of_type(l, "DDATA").filter(|d| d["device"] == "wj").count() > historical + 5
        },
    )
    .await;
    let lines = host.lines();
    no_errors(&lines);
    assert_seq_unbroken(&lines);
    let totals = assert_sparkplug_exact(&lines, "wj", "a0");
    assert!(
        totals.len() > 15,
        "{} totals after the outage",
        totals.len()
    );
    assert_json_exact(&sub, topic);
}

/// With its primary host offline the Sparkplug output holds, and `/healthz` names it held while
/// within its grace; the JSON output keeps flowing all the while. That a hold past the grace
/// makes the gateway not well is health's arithmetic, told on made-up instants in
/// `src/health/vitals_tests.rs` (`an_output_held_or_down_is_not_well_after_the_grace_only`): no
/// half minute of wall clock here.
pub(crate) async fn a_primary_host_offline_holds_sparkplug_only() {
    let (local, scada) = (Broker::start(), Broker::start());
    let host = Host::start(scada.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("outputs-primary");
    let http = free_port();
    let extra = format!("primary_host = \"scada\"\n[metrics]\nlisten = \"127.0.0.1:{http}\"\n");
    let topic = "pulsegate/test/wj/a0";
    let sub = Subscriber::start(local.port, topic).await;
    let _gw = Gateway::start(&two_brokers(&plant, local.port, scada.port, &dir, &extra));
    sub.expect_any(topic, Duration::from_secs(10)).await;
    let text = scrape_until(http, Duration::from_secs(10), "held", |t| {
        sample(t, "pulsegate_mqtt_held{output=\"scada\"}") == Some(1.0)
            && sample(t, "pulsegate_mqtt_connected{output=\"scada\"}") == Some(1.0)
    })
    .await;
    assert_eq!(
        sample(&text, "pulsegate_mqtt_held{output=\"local\"}"),
        Some(0.0)
    );
    let (code, body) = tokio::task::spawn_blocking(move || http_get(http, "/healthz"))
        .await
        .unwrap();
    assert_eq!(code, 200, "within the grace: {body}");
    assert!(body.contains("output/scada held"), "{body}");
    let flowed = sub
        .wait_more_than(topic, 100, Duration::from_secs(30))
        .await;
    assert!(flowed > 100, "JSON flowed while Sparkplug held: {flowed}");
    let (code, body) = tokio::task::spawn_blocking(move || http_get(http, "/healthz"))
        .await
        .unwrap();
    assert!(
        body.contains("output/scada held"),
        "still held: {code} {body}"
    );
    assert!(
        of_type(&host.lines(), "NBIRTH").next().is_none(),
        "no birth without the host"
    );
    assert_json_exact(&sub, topic);
}

/// A Sparkplug-only config: no output carries the gateway's JSON topics, so its voice has a
/// connection of its own: `pulsegate set-reading` is answered, and a DCMD clear is executed and
/// answered to the host as the node's `Command/*` metrics.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sparkplug_only_gateway_answers_set_reading_and_a_dcmd() {
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("outputs-sparkplug-only");
    let extra = "[outputs.scada]\nkind = \"sparkplug\"\n[sparkplug]\ngroup_id = \"plant\"\n\
                 [buses.line1.devices.wj.channels.a0]\nscale = 0.001\nunit = \"kWh\"\n";
    let status = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let config = write_config(
        &dir,
        &gateway_toml(&plant, broker.port, &dir, &DEVICES, extra),
    );
    let _gw = Gateway::start(&config);
    host.wait(Duration::from_secs(15), "born", |l| {
        of_type(l, "DBIRTH").count() >= 2
    })
    .await;
    status
        .wait_for("pulsegate/test/status", Duration::from_secs(5), |m| {
            m.payload == "online"
        })
        .await
        .expect("the gateway's own connection says it is online");
    assert!(
        status
            .all()
            .iter()
            .all(|m| m.topic == "pulsegate/test/status" || m.topic == "pulsegate/test/gateway"),
        "no JSON readings: {:?}",
        status.all().iter().map(|m| &m.topic).collect::<Vec<_>>()
    );
    let out = std::process::Command::new(bin())
        .args(["set-reading", "--config"])
        .arg(&config)
        .args(["wj", "a0", "20000"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let said: Value = serde_json::from_slice(&out.stdout).unwrap();
    assert_eq!(said["ok"], true, "{said}");
    host.send(json!({"dcmd": "plant/test/wj", "metric": "a0/Clear", "value": true}));
    host.wait(Duration::from_secs(10), "the clear answered", |l| {
        of_type(l, "NDATA").any(|n| {
            metric(n, "Command/Metric").is_some_and(|m| m["value"] == "a0/Clear")
                && metric(n, "Command/Result").is_some_and(|m| m["value"] == "ok")
        })
    })
    .await;
    host.wait(Duration::from_secs(10), "the clear in the data", |l| {
        of_type(l, "DDATA").any(|d| metric(d, "a0/Event").is_some_and(|m| m["value"] == "cleared"))
    })
    .await;
    // A metric that is not writable is refused whole, and the host is told why.
    host.send(json!({"dcmd": "plant/test/wj", "metric": "a0/x/Clear", "value": true}));
    host.wait(Duration::from_secs(10), "the refusal", |l| {
        of_type(l, "NDATA").any(|n| {
            metric(n, "Command/Metric").is_some_and(|m| m["value"] == "a0/x/Clear")
                && metric(n, "Command/Result").is_some_and(|m| m["value"] == "not_writable")
        })
    })
    .await;
    no_errors(&host.lines());
}

/// Ten thousand DCMDs in a burst: every one is executed or refused and counted, none dropped
/// silently (an answer the outbox could not keep is counted as dropped chatter), and the
/// readings stay exact throughout.
/// Run from `burn_in` (it starts with the other long runs).
pub(crate) async fn ten_thousand_dcmds_in_a_burst_are_each_answered_or_counted() {
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(PLANT).await;
    let dir = temp_dir("outputs-dcmd-flood");
    let http = free_port();
    let extra = format!(
        "[outputs.scada]\nkind = \"sparkplug\"\n[sparkplug]\ngroup_id = \"plant\"\n\
         [metrics]\nlisten = \"127.0.0.1:{http}\"\n"
    );
    let _gw = Gateway::start(&write_config(
        &dir,
        &gateway_toml(&plant, broker.port, &dir, &DEVICES, &extra),
    ));
    host.wait(Duration::from_secs(15), "born", |l| {
        of_type(l, "DDATA").count() >= 5
    })
    .await;
    const N: u64 = 10_000;
    host.send(json!({"dcmd": "plant/test/yl", "metric": "enc0/Clear", "value": true, "count": N}));
    scrape_until(http, Duration::from_secs(60), "every DCMD counted", |t| {
        sample(t, "pulsegate_commands_received_total") == Some(N as f64)
    })
    .await;
    // The answers trail the count (the host reads them one by one): wait until every DCMD is
    // answered or counted as dropped, and no longer.
    let deadline = std::time::Instant::now() + Duration::from_secs(60);
    let (lines, answered, dropped, text) = loop {
        let lines = host.lines();
        let answered = of_type(&lines, "NDATA")
            .filter(|n| metric(n, "Command/Metric").is_some_and(|m| m["value"] == "enc0/Clear"))
            .count() as u64;
        let text = scrape_until(http, Duration::from_secs(5), "a scrape", |_| true).await;
        let dropped = sample(
            &text,
            "pulsegate_mqtt_chatter_dropped_total{output=\"scada\"}",
        )
        .unwrap_or(0.0) as u64;
        if answered + dropped >= N || std::time::Instant::now() > deadline {
            break (lines, answered, dropped, text);
        }
        tokio::time::sleep(Duration::from_millis(500)).await;
    };
    println!("DCMD burst: {answered} answered to the host, {dropped} answers dropped and counted");
    assert_eq!(
        answered + dropped,
        N,
        "every DCMD answered or its answer counted as dropped"
    );
    let refused: f64 = text
        .lines()
        .filter(|l| l.starts_with("pulsegate_commands_refused_total{"))
        .filter_map(|l| l.rsplit(' ').next()?.parse::<f64>().ok())
        .sum();
    assert!(
        refused > 0.0,
        "a burst beyond the rate limit is refused, and counted"
    );
    no_errors(&lines);
    assert_seq_unbroken(&lines);
    let totals = assert_sparkplug_exact(&lines, "wj", "a0");
    assert!(totals.len() > 20, "{} readings of wj/a0", totals.len());
}

//! Tariffs and billing end to end: the simulator on a pseudo-terminal, a real Mosquitto, the
//! gateway binary with its wall clock set by libfaketime to the date that matters (a Friday
//! morning, the spring-forward night, a local midnight). The monotonic clock stays real, so
//! these run in real time: a boundary has to be read to be a boundary.

use std::path::{Path, PathBuf};
use std::time::{Duration, SystemTime};

use serde_json::Value;

use crate::metering::{SERIAL_115200, metering_toml, wall_ms};
use crate::support::*;

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

pub(crate) fn ms_of(text: &str) -> i64 {
    let t = humantime::parse_rfc3339(text).unwrap();
    t.duration_since(SystemTime::UNIX_EPOCH)
        .unwrap()
        .as_millis() as i64
}

fn iso_ms(v: &Value) -> i64 {
    ms_of(v.as_str().unwrap_or_else(|| panic!("a time: {v}")))
}

/// A gateway whose wall clock reads `fake` (RFC 3339) now and runs on from there.
pub(crate) struct Faked {
    rc: PathBuf,
    /// Fake minus real, in ms.
    offset_ms: i64,
}

impl Faked {
    pub(crate) fn at(dir: &Path, fake: &str) -> Faked {
        let offset_s = (ms_of(fake) - wall_ms()) / 1000;
        let rc = dir.join("faketime.rc");
        std::fs::write(&rc, format!("{offset_s:+}\n")).unwrap();
        Faked {
            rc,
            offset_ms: offset_s * 1000,
        }
    }

    pub(crate) fn start(&self, config: &Path) -> Gateway {
        Gateway::start_with_env(
            config,
            &[
                ("LD_PRELOAD", libfaketime()),
                ("FAKETIME_TIMESTAMP_FILE", self.rc.to_str().unwrap()),
                ("FAKETIME_NO_CACHE", "1"),
                ("FAKETIME_DONT_FAKE_MONOTONIC", "1"),
            ],
        )
    }

    /// Sleeps until the gateway's clock reads `fake`.
    async fn until(&self, fake: &str) {
        crate::metering::until_wall(ms_of(fake) - self.offset_ms).await;
    }
}

const TARIFFS: &str = "[tariffs]\ndefault = \"offpeak\"\nholidays = [\"2026-12-25\"]\n\
    [[tariffs.rule]]\ntariff = \"peak\"\ndays = [\"mon\", \"tue\", \"wed\", \"thu\", \"fri\"]\n\
    from = \"07:00\"\nto = \"21:00\"\n";

pub(crate) struct Run {
    pub(crate) dir: PathBuf,
    pub(crate) broker: Broker,
    pub(crate) sub: Subscriber,
    pub(crate) config: PathBuf,
    _plant: pulsegate::sim::Plant,
}

pub(crate) async fn setup(name: &str, rate: f64, gateway: &str, extra: &str) -> Run {
    let dir = temp_dir(name);
    let broker = Broker::start();
    let plant = plant(&format!(
        "[buses.line1.devices.m1]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = {{ rate = {rate} }}\n"
    ))
    .await;
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = metering_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "m1", 1, "yl67", "1s")],
        &format!("state_flush = \"500ms\"\ntimezone = \"Europe/Berlin\"\n{gateway}"),
        SERIAL_115200,
        &format!(
            "[buses.line1.devices.m1.channels.a0]\nscale = 0.001\nunit = \"kWh\"\ndevice_class = \"energy\"\n{extra}"
        ),
    );
    let config = write_config(&dir, &text);
    Run {
        dir,
        broker,
        sub,
        config,
        _plant: plant,
    }
}

/// Waits for the record of `topic` that starts at `start`.
pub(crate) async fn record_from(sub: &Subscriber, topic: &str, start: &str, secs: u64) -> Value {
    let at = ms_of(start);
    sub.wait_for(topic, Duration::from_secs(secs), |m| {
        m.json()["start"].as_str().map(ms_of) == Some(at)
    })
    .await
    .unwrap_or_else(|| panic!("a record from {start} on {topic}"))
    .json()
}

/// Each tariff's register messages against the records booked to it: every register message
/// is the running sum of its tariff's records so far, and the last is their sum.
fn registers_match_records(sub: &Subscriber, records: &[Value], base: &str) {
    for tariff in ["offpeak", "peak"] {
        let regs = readings(sub, &format!("{base}/tariff/{tariff}"));
        let mine: Vec<&Value> = records.iter().filter(|r| r["tariff"] == tariff).collect();
        assert_eq!(
            regs.len(),
            mine.len(),
            "one register message per {tariff} record"
        );
        let mut sum = 0;
        for (reg, rec) in regs.iter().zip(&mine) {
            sum += rec["delta"].as_i64().unwrap();
            assert_eq!(
                reg["total"].as_i64().unwrap(),
                sum,
                "{tariff}: {reg} after {rec}"
            );
            assert_eq!(reg["unit"], "kWh");
            let value = pulsegate::decimal::Decimal::parse(&reg["value"].to_string()).unwrap();
            let want = pulsegate::decimal::Decimal::parse("0.001")
                .unwrap()
                .times(sum);
            assert_eq!(value.to_string(), want.to_string(), "an exact value");
        }
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_friday_morning_across_the_peak_rule_books_each_record_to_its_tariff_and_register() {
    // Five-second records (the shortest that leave the gateway room to start before the
    // first boundary it reads): the rule's start is crossed in under 20 s of wall clock.
    let r = setup(
        "friday",
        40.0,
        "intervals = [\"5s\"]\n",
        "obis = \"1-0:1.8.0\"\n",
    )
    .await;
    let text = std::fs::read_to_string(&r.config).unwrap() + TARIFFS;
    std::fs::write(&r.config, text).unwrap();
    // Friday 4 December 2026, 06:59:51 CET.
    let fake = Faked::at(&r.dir, "2026-12-04T05:59:51Z");
    let gw = fake.start(&r.config);
    let base = "pulsegate/test/m1/a0";
    let topic = format!("{base}/interval/5s");
    record_from(&r.sub, &topic, "2026-12-04T06:00:05Z", 90).await;
    drop(gw);
    let records = readings(&r.sub, &topic);
    assert!(records.len() >= 3, "{records:#?}");
    for rec in &records {
        let start = iso_ms(&rec["start"]);
        let want = if start < ms_of("2026-12-04T06:00:00Z") {
            "offpeak"
        } else {
            "peak"
        };
        assert_eq!(rec["tariff"], want, "{rec}");
        assert_eq!(rec["status"], "complete", "{rec}");
    }
    assert!(records.iter().any(|r| r["tariff"] == "offpeak"));
    registers_match_records(&r.sub, &records, base);
    // The channel's OBIS name rides on its readings and records; a tariff's register takes
    // the tariff's number in the calendar (the default first) as its last group.
    let read = readings(&r.sub, base);
    assert!(
        !read.is_empty() && read.iter().all(|m| m["obis"] == "1-0:1.8.0"),
        "{read:?}"
    );
    assert!(
        records.iter().all(|m| m["obis"] == "1-0:1.8.0"),
        "{records:?}"
    );
    for (tariff, obis) in [("offpeak", "1-0:1.8.1"), ("peak", "1-0:1.8.2")] {
        let regs = readings(&r.sub, &format!("{base}/tariff/{tariff}"));
        assert!(
            !regs.is_empty() && regs.iter().all(|m| m["obis"] == obis),
            "{regs:?}"
        );
    }
    let _ = &r.broker;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_berlin_spring_forward_night_keeps_records_tiling_utc_and_the_tariff_local() {
    let tariffs = "[tariffs]\ndefault = \"offpeak\"\n\
        [[tariffs.rule]]\ntariff = \"night\"\ndays = [\"sun\"]\nfrom = \"00:00\"\nto = \"03:00\"\n\
        [[tariffs.rule]]\ntariff = \"peak\"\ndays = [\"sun\"]\nfrom = \"03:00\"\nto = \"00:00\"\n";
    // Five-second records: the jump is crossed in under 20 s of wall clock.
    let r = setup("spring", 30.0, "intervals = [\"5s\"]\n", "").await;
    let text = std::fs::read_to_string(&r.config).unwrap() + tariffs;
    std::fs::write(&r.config, text).unwrap();
    // Sunday 29 March 2026, 01:59:51 CET; at 02:00 CET (01:00Z) the clock jumps to 03:00 CEST.
    let fake = Faked::at(&r.dir, "2026-03-29T00:59:51Z");
    let gw = fake.start(&r.config);
    let base = "pulsegate/test/m1/a0";
    let topic = format!("{base}/interval/5s");
    let after = record_from(&r.sub, &topic, "2026-03-29T01:00:00Z", 90).await;
    drop(gw);
    let before = readings(&r.sub, &topic)
        .into_iter()
        .find(|x| x["end"] == after["start"])
        .expect("the record before the jump");
    assert_eq!(before["start"], "2026-03-29T00:59:55Z", "01:59:55 CET");
    assert_eq!(before["tariff"], "night", "{before}");
    assert_eq!(
        after["end"], "2026-03-29T01:00:05Z",
        "03:00:05 CEST: 5 s in UTC"
    );
    assert_eq!(after["tariff"], "peak", "{after}");
    for rec in [&before, &after] {
        assert_eq!(iso_ms(&rec["end"]) - iso_ms(&rec["start"]), 5_000);
        assert_eq!(rec["status"], "complete");
    }
    assert_eq!(after["total_start"], before["total_end"], "they tile");
    // Each tariff's register is the sum of the records booked to it.
    let records = readings(&r.sub, &topic);
    for tariff in ["night", "peak"] {
        let register = readings(&r.sub, &format!("{base}/tariff/{tariff}"));
        let booked: i64 = records
            .iter()
            .filter(|x| x["tariff"] == tariff)
            .take(register.len())
            .map(|x| x["delta"].as_i64().unwrap())
            .sum();
        assert_eq!(register.last().unwrap()["total"], booked, "{tariff}");
    }
    let _ = &r.broker;
}

/// The largest complete 10 s record among `records` inside `[from, to)`, the first on a tie.
fn largest(records: &[Value], from: i64, to: i64) -> Value {
    let mut best: Option<&Value> = None;
    for r in records {
        let (s, e) = (iso_ms(&r["start"]), iso_ms(&r["end"]));
        if r["status"] != "complete" || s < from || e > to {
            continue;
        }
        if best.is_none_or(|b| r["delta"].as_i64() > b["delta"].as_i64()) {
            best = Some(r);
        }
    }
    best.expect("a complete record").clone()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_daily_period_with_a_stop_and_a_start_inside_closes_at_midnight_whole_with_its_demand() {
    // Peak only in the last minute of Friday, so the day has both tariffs in a minute.
    let tariffs = "[tariffs]\ndefault = \"offpeak\"\n[[tariffs.rule]]\ntariff = \"peak\"\n\
        days = [\"fri\"]\nfrom = \"23:59\"\nto = \"00:00\"\n\
        [billing]\nperiod = \"daily\"\ndemand = \"10s\"\n";
    let r = setup(
        "daily",
        25.0,
        "intervals = [\"10s\"]\n",
        "obis = \"1-0:1.8.0\"\n",
    )
    .await;
    let text = std::fs::read_to_string(&r.config).unwrap() + tariffs;
    std::fs::write(&r.config, text).unwrap();
    // Friday 4 December 2026, 23:58:56 CET, four seconds before peak: the read of 23:59:00
    // that opens the first record counted its pulses in off-peak, and the partial period
    // books them there, so its peak is exactly its peak records. Local midnight is 23:00Z.
    let fake = Faked::at(&r.dir, "2026-12-04T22:58:56Z");
    let mut gw = fake.start(&r.config);
    let base = "pulsegate/test/m1/a0";
    // Offpeak, then peak from 23:59; a stop at 23:59:05 over the boundaries to 23:59:40: the
    // gateway's clock moves on by 39 s while it is stopped (libfaketime's offset set anew for
    // the restart), as a stop of that length would, and the wall waits for none of it.
    fake.until("2026-12-04T22:59:05Z").await;
    let (status, _) = gw.terminate();
    assert!(status.success());
    let fake = Faked::at(&r.dir, "2026-12-04T22:59:44Z");
    gw = fake.start(&r.config);
    let billing = r
        .sub
        .wait_for(&format!("{base}/billing"), Duration::from_secs(60), |_| {
            true
        })
        .await
        .expect("a billing record at midnight")
        .json();
    let rec_topic = format!("{base}/interval/10s");
    record_from(&r.sub, &rec_topic, "2026-12-04T22:59:50Z", 10).await;
    drop(gw);

    let first = readings(&r.sub, base)
        .into_iter()
        .next()
        .expect("a reading");
    assert_eq!(
        billing["status"], "partial",
        "the gateway began inside: {billing}"
    );
    assert_eq!(
        iso_ms(&billing["start"]),
        iso_ms(&first["ts"]),
        "from the first reading"
    );
    assert_eq!(billing["total_start"], first["total"]);
    assert_eq!(billing["end"], "2026-12-04T23:00:00Z");
    let delta = billing["delta"].as_i64().unwrap();
    assert_eq!(
        delta,
        billing["total_end"].as_i64().unwrap() - billing["total_start"].as_i64().unwrap()
    );
    let by: i64 = billing["by_tariff"]
        .as_object()
        .unwrap()
        .values()
        .map(|v| v.as_i64().unwrap())
        .sum();
    assert_eq!(by, delta, "by_tariff sums to delta: {billing}");
    let records = readings(&r.sub, &rec_topic);
    let closing = records
        .iter()
        .find(|x| x["end"] == "2026-12-04T23:00:00Z")
        .unwrap();
    assert_eq!(billing["total_end"], closing["total_end"]);
    let peak: i64 = records
        .iter()
        .filter(|x| x["tariff"] == "peak" && iso_ms(&x["end"]) <= ms_of("2026-12-04T23:00:00Z"))
        .map(|x| x["delta"].as_i64().unwrap())
        .sum();
    assert_eq!(
        billing["by_tariff"]["peak"].as_i64().unwrap(),
        peak,
        "{billing}\n{records:#?}"
    );
    assert!(
        records.iter().any(|x| x["status"] == "merged"),
        "the stop made a merged record"
    );
    let best = largest(
        &records,
        iso_ms(&billing["start"]),
        ms_of("2026-12-04T23:00:00Z"),
    );
    let kw = pulsegate::decimal::Decimal::parse("0.001")
        .unwrap()
        .times(best["delta"].as_i64().unwrap() * 360);
    assert_eq!(
        billing["demand"]["value"].to_string(),
        kw.to_string(),
        "{billing} vs {best}"
    );
    assert_eq!(billing["demand"]["unit"], "kW");
    assert_eq!(billing["demand"]["start"], best["start"]);
    assert_eq!(billing["obis"], "1-0:1.8.0");
    assert_eq!(
        billing["demand"]["obis"], "1-0:1.6.0",
        "the maximum demand's OBIS name"
    );

    // `pulsegate billing` prints the same period from the state file.
    let out = std::process::Command::new(env!("CARGO_BIN_EXE_pulsegate"))
        .args(["billing", "--config", r.config.to_str().unwrap(), "--json"])
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let line: Value = serde_json::from_str(text.lines().next().expect("a line")).unwrap();
    assert_eq!(
        (&line["device"], &line["channel"]),
        (&"m1".into(), &"a0".into())
    );
    for k in ["start", "end", "delta", "by_tariff", "status", "seq"] {
        assert_eq!(line[k], billing[k], "{k}: {text}");
    }
    assert_eq!(line["demand"]["value"].as_str().unwrap(), kw.to_string());
    let _ = &r.broker;
}

//! Plants that behave as the datasheets say: ZH-YX1600 counters stopped after power-up, modules
//! of the wrong model, devices that come and go. The simulator on pseudo-terminals, a real
//! Mosquitto, the gateway binary.

use std::path::PathBuf;
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;
use serde_json::Value;

use crate::support::*;

fn running(plant: &Plant, unit: u8, ch: &str) -> bool {
    plant
        .with_module("line1", unit, |m, _| m.channel(ch).unwrap().running())
        .unwrap()
}

fn count(plant: &Plant, unit: u8, ch: &str) -> i64 {
    plant
        .with_module("line1", unit, |m, now| m.channel(ch).unwrap().count(now))
        .unwrap()
}

fn set_rate(plant: &Plant, unit: u8, ch: &str, rate: f64) {
    plant
        .with_module("line1", unit, |m, now| assert!(m.set_rate(now, ch, rate)))
        .unwrap();
}

async fn reading_after(sub: &Subscriber, topic: &str, after: Instant) -> Value {
    sub.wait_for(topic, Duration::from_secs(10), |m| m.at > after)
        .await
        .unwrap_or_else(|| panic!("a reading on {topic}"))
        .json()
}

async fn wait_until(what: &str, timeout: Duration, f: impl Fn() -> bool) -> Duration {
    let t = Instant::now();
    while !f() {
        assert!(t.elapsed() < timeout, "{what} within {timeout:?}");
        tokio::time::sleep(Duration::from_millis(5)).await;
    }
    t.elapsed()
}

struct Setup {
    broker: Broker,
    plant: Plant,
    dir: PathBuf,
    config: PathBuf,
    sub: Subscriber,
}

async fn setup(
    name: &str,
    sim: &str,
    devices: &[(&str, &str, u8, &str, &str)],
    extra: &str,
) -> Setup {
    let broker = Broker::start();
    let plant = plant(sim).await;
    let dir = temp_dir(name);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let config = write_config(
        &dir,
        &gateway_toml(&plant, broker.port, &dir, devices, extra),
    );
    Setup {
        broker,
        plant,
        dir,
        config,
        sub,
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zh_yx1600_at_factory_defaults_power_cycled_while_polled_counts_on_within_one_poll() {
    let s = setup(
        "zh-factory",
        "[buses.line1.devices.zh]\nunit = 1\nmodel = \"zh-yx1600\"\n",
        &[("line1", "zh", 1, "zh-yx1600", "200ms")],
        "[buses.line1.devices.zh.channels.di3]\nrun = \"leave\"\n",
    )
    .await;
    let topic = "pulsegate/test/zh/di1";
    assert!(!running(&s.plant, 1, "di1"), "factory state: stopped");
    let _gateway = Gateway::start(&s.config);
    let first = reading_after(&s.sub, topic, Instant::now()).await;
    assert_eq!(first["event"], "reset", "the start is said: {first}");
    assert!(running(&s.plant, 1, "di1"), "the gateway started it");
    assert!(
        !running(&s.plant, 1, "di3"),
        "run = \"leave\" is left stopped"
    );

    set_rate(&s.plant, 1, "di1", 500.0);
    wait_until("600 pulses", Duration::from_secs(10), || {
        count(&s.plant, 1, "di1") >= 600
    })
    .await;
    set_rate(&s.plant, 1, "di1", 0.0);
    reading_after(&s.sub, topic, Instant::now() + Duration::from_millis(300)).await;
    let before = count(&s.plant, 1, "di1");
    assert!(before >= 600, "counted {before}");

    // Power cut: the counter comes back cleared and stopped (pAuto 0).
    set_rate(&s.plant, 1, "di1", 500.0);
    s.plant
        .with_module("line1", 1, |m, now| m.power_cycle(now))
        .unwrap();
    assert!(!running(&s.plant, 1, "di1"));
    let took = wait_until("counting resumes", Duration::from_secs(2), || {
        running(&s.plant, 1, "di1")
    })
    .await;
    eprintln!("counting resumed {took:?} after the power cut (poll 200 ms)");
    // One poll interval plus one transaction (with room for a loaded test machine).
    assert!(took <= Duration::from_millis(200 + 300), "took {took:?}");
    wait_until("600 pulses after", Duration::from_secs(10), || {
        count(&s.plant, 1, "di1") >= 600
    })
    .await;
    set_rate(&s.plant, 1, "di1", 0.0);
    let last = reading_after(&s.sub, topic, Instant::now() + Duration::from_millis(400)).await;
    let after = count(&s.plant, 1, "di1");
    assert!(after >= 600, "counted {after} after the power cut");
    assert_eq!(
        last["total"].as_i64().unwrap(),
        before + after,
        "total = the pulses the module counted"
    );
    let resets = readings(&s.sub, topic)
        .iter()
        .filter(|r| r["event"] == "reset")
        .count();
    assert_eq!(resets, 2, "the first start and the one after the power cut");
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_yl67_configured_as_wj157_and_a_zh_yx1600_as_yl67_are_wrong_models_with_no_readings() {
    let metrics_port = free_port();
    let s = setup(
        "wrong-model",
        "[buses.line1.devices.yl]\nunit = 1\nmodel = \"yl67\"\nmodes = [0, 0, 0, 0]\n\
         channels.enc0 = { rate = 100 }\n\
         [buses.line1.devices.zh]\nunit = 2\nmodel = \"zh-yx1600\"\n\
         [buses.line1.devices.good]\nunit = 3\nmodel = \"wj157\"\n",
        &[
            ("line1", "yl", 1, "wj157", "100ms"),
            ("line1", "zh", 2, "yl67", "100ms"),
            ("line1", "good", 3, "wj157", "100ms"),
        ],
        &format!("[metrics]\nlisten = \"127.0.0.1:{metrics_port}\"\n"),
    )
    .await;
    let gateway = Gateway::start(&s.config);
    for dev in ["yl", "zh"] {
        let topic = format!("pulsegate/test/{dev}/status");
        s.sub
            .wait_for(&topic, Duration::from_secs(5), |m| {
                m.payload == "wrong_model"
            })
            .await
            .unwrap_or_else(|| panic!("{dev}: status wrong_model"));
        // A subscriber arriving later gets it from the broker: retained.
        let late = Subscriber::start(s.broker.port, &topic).await;
        let m = late
            .wait_for(&topic, Duration::from_secs(2), |_| true)
            .await
            .expect("a retained status");
        assert_eq!((m.payload.as_str(), m.retain), ("wrong_model", true));
    }
    // The right model next to them publishes as usual.
    reading_after(&s.sub, "pulsegate/test/good/enc0", Instant::now()).await;
    tokio::time::sleep(Duration::from_secs(1)).await;
    let from_wrong: Vec<_> = s
        .sub
        .all()
        .into_iter()
        .filter(|m| {
            (m.topic.starts_with("pulsegate/test/yl/") || m.topic.starts_with("pulsegate/test/zh/"))
                && !m.topic.ends_with("/status")
        })
        .collect();
    assert!(
        from_wrong.is_empty(),
        "readings from a wrong model: {from_wrong:?}"
    );
    let statuses: Vec<String> = s
        .sub
        .on("pulsegate/test/yl/status")
        .into_iter()
        .map(|m| m.payload)
        .collect();
    assert!(!statuses.contains(&"online".to_string()), "{statuses:?}");
    let log = gateway.log_text();
    assert!(
        log.contains("the module says [0x0067] at register 210") && log.contains("yl67 (ibf67)"),
        "the log names what the module said and what it is"
    );
    assert!(
        log.contains("identifies as zh-yx1600"),
        "the ZH-YX1600 is named"
    );
    // The metrics show which modules are the wrong model.
    let wrong =
        |dev: &str| format!("pulsegate_device_wrong_model{{bus=\"line1\",device=\"{dev}\"}}");
    let scraped = crate::metrics::scrape_until(
        metrics_port,
        Duration::from_secs(10),
        "wrong_model 1 for yl and zh, 0 for good",
        |t| {
            use crate::metrics::sample;
            sample(t, &wrong("yl")) == Some(1.0)
                && sample(t, &wrong("zh")) == Some(1.0)
                && sample(t, &wrong("good")) == Some(0.0)
        },
    )
    .await;
    assert_eq!(
        crate::metrics::sample(&scraped, "pulsegate_device_up{bus=\"line1\",device=\"yl\"}"),
        Some(0.0),
        "a wrong model is not up"
    );
    let _ = (&s.broker, &s.dir);
}

/// Waits until the gateway's log has said `needle` `n` times.
/// Puts a module of `model` (in work `modes`) at unit 1 of line1 in place of the meter, and
/// waits for the gateway to say `wrong_model` for it. Returns when the module was swapped.
async fn swap_in_and_expect_wrong_model(s: &Setup, model: &str, modes: &[u16]) -> Instant {
    wire_module(&s.plant, "line1", 1, model, modes);
    let swapped = Instant::now();
    s.sub
        .wait_for("pulsegate/test/meter/status", Duration::from_secs(5), |m| {
            m.at > swapped && m.payload == "wrong_model"
        })
        .await
        .expect("wrong_model after the reset");
    swapped
}

async fn wait_log(gateway: &Gateway, needle: &str, n: usize) {
    let t = Instant::now();
    while gateway.log_text().matches(needle).count() < n {
        assert!(t.elapsed() < Duration::from_secs(10), "log: {needle} x{n}");
        tokio::time::sleep(Duration::from_millis(20)).await;
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_removed_by_sighup_or_disabled_and_put_back_continues_its_total_with_a_gap() {
    let s = setup(
        "come-and-go",
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n\
         [buses.line1.devices.other]\nunit = 2\nmodel = \"wj157\"\n",
        &[
            ("line1", "meter", 1, "yl67", "100ms"),
            ("line1", "other", 2, "wj157", "100ms"),
        ],
        "",
    )
    .await;
    let full = std::fs::read_to_string(&s.config).unwrap();
    let without = gateway_toml(
        &s.plant,
        s.broker.port,
        &s.dir,
        &[("line1", "other", 2, "wj157", "100ms")],
        "",
    );
    let disabled = format!("{full}\n[buses.line1.devices.meter.channels.a1]\nenabled = true\n")
        .replace("model = \"yl67\"\n", "model = \"yl67\"\nenabled = false\n");
    let channel_off = format!("{full}\n[buses.line1.devices.meter.channels.a0]\nenabled = false\n");
    let topic = "pulsegate/test/meter/a0";
    let gateway = Gateway::start(&s.config);
    reading_after(&s.sub, topic, Instant::now()).await;
    let plant = &s.plant;
    let generated = || {
        plant
            .with_module("line1", 1, |m, now| m.channel("a0").unwrap().generated(now))
            .unwrap()
    };
    async fn pulses(plant: &Plant) {
        let generated = || {
            plant
                .with_module("line1", 1, |m, now| m.channel("a0").unwrap().generated(now))
                .unwrap()
        };
        let from = generated();
        set_rate(plant, 1, "a0", 300.0);
        wait_until("300 pulses", Duration::from_secs(10), || {
            generated() >= from + 300
        })
        .await;
        set_rate(plant, 1, "a0", 0.0);
    }
    pulses(plant).await;
    let before = reading_after(&s.sub, topic, Instant::now() + Duration::from_millis(300)).await;
    assert_eq!(before["total"].as_i64().unwrap(), generated());

    let mut reloads = 0;
    for (round, away) in [
        ("removed", &without),
        ("disabled", &disabled),
        ("channel disabled", &channel_off),
    ] {
        std::fs::write(&s.config, away).unwrap();
        gateway.signal("HUP");
        reloads += 1;
        wait_log(&gateway, "config reloaded", reloads).await;
        let gone = Instant::now();
        // Pulses while the device is away, and state flushes (every 500 ms) meanwhile.
        pulses(plant).await;
        tokio::time::sleep(Duration::from_millis(1200)).await;
        assert!(
            s.sub.on(topic).iter().all(|m| m.at < gone),
            "{round}: no readings while away"
        );
        std::fs::write(&s.config, &full).unwrap();
        gateway.signal("HUP");
        reloads += 1;
        wait_log(&gateway, "config reloaded", reloads).await;
        let back = reading_after(&s.sub, topic, gone).await;
        assert_eq!(back["event"], "gap", "{round}: {back}");
        assert_eq!(
            back["total"].as_i64().unwrap(),
            generated(),
            "{round}: the total continues from where it was, with the pulses counted meanwhile"
        );
    }
    let _ = &s.broker;
}

#[test]
fn state_list_shows_what_is_saved_and_prune_removes_the_unmatched_only_with_apply() {
    let dir = temp_dir("state-cli");
    let config = write_config(
        &dir,
        &format!(
            "[gateway]\nid = \"t\"\nstate_dir = {dir:?}\n[buses.line1]\nport = \"/dev/ttyS0\"\n\
             [buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n"
        ),
    );
    let file = dir.join("bus-line1.json");
    std::fs::write(
        &file,
        r#"{"version":1,"channels":{
            "1/yl67/a0":{"count":200,"at_ms":1795300723123,"total":200,"seq":9},
            "7/wj157/a0":{"count":75,"at_ms":1795300723123,"total":75,"seq":3}},"holes":{}}"#,
    )
    .unwrap();
    let run = |args: &[&str]| {
        let out = std::process::Command::new(bin())
            .args(args)
            .arg("--config")
            .arg(&config)
            .output()
            .unwrap();
        assert!(out.status.success(), "{args:?}: {out:?}");
        String::from_utf8(out.stdout).unwrap()
    };
    let list = run(&["state", "list"]);
    assert!(
        list.contains("1/yl67/a0") && list.contains("device meter"),
        "{list}"
    );
    assert!(
        list.contains("7/wj157/a0") && list.contains("matches no configured device"),
        "{list}"
    );
    let dry = run(&["state", "prune"]);
    assert!(
        dry.contains("would remove") && dry.contains("7/wj157/a0"),
        "{dry}"
    );
    assert!(
        std::fs::read_to_string(&file)
            .unwrap()
            .contains("7/wj157/a0"),
        "a dry run"
    );
    run(&["state", "prune", "--apply"]);
    let after = std::fs::read_to_string(&file).unwrap();
    assert!(
        !after.contains("7/wj157/a0") && after.contains("1/yl67/a0"),
        "{after}"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zh_yx1600_frequency_is_published_in_hz_from_its_counting_window() {
    let s = setup(
        "zh-window",
        "[buses.line1.devices.zh]\nunit = 1\nmodel = \"zh-yx1600\"\nchannels.di1 = { rate = 400 }\n",
        &[("line1", "zh", 1, "zh-yx1600", "200ms")],
        "",
    )
    .await;
    // Counter 1's window at 0x1140:0x1141 = 50 × 10 ms: the register holds pulses per 0.5 s.
    s.plant
        .with_module("line1", 1, |m, now| m.write_many(now, 0x1140, &[0, 50]))
        .unwrap()
        .unwrap();
    let _gateway = Gateway::start(&s.config);
    let topic = "pulsegate/test/zh/di1";
    let t = Instant::now() + Duration::from_millis(800);
    let r = s
        .sub
        .wait_for(topic, Duration::from_secs(5), |m| {
            m.at > t && m.json()["freq_hz"].is_number()
        })
        .await
        .expect("a reading with a frequency")
        .json();
    let raw = s
        .plant
        .with_module("line1", 1, |m, now| m.read(now, 0x1180, 2))
        .unwrap()
        .unwrap();
    assert_eq!(raw, vec![0, 200], "the module's register: pulses in 0.5 s");
    assert_eq!(r["freq_hz"].as_f64().unwrap(), 400.0, "{r}");
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_zh_yx1600_quadrature_pair_with_disagreeing_mode_words_is_reported_not_published() {
    // Pair 1 (counters 1+2) in quadrature on both words; pair 2: only counter 3's word.
    let s = setup(
        "zh-mismatch",
        "[buses.line1.devices.zh]\nunit = 1\nmodel = \"zh-yx1600\"\nmodes = [2, 2]\n",
        &[("line1", "zh", 1, "zh-yx1600", "200ms")],
        "",
    )
    .await;
    s.plant
        .with_module("line1", 1, |m, now| {
            m.write_one(now, 0x0703, 0x0000).unwrap();
            m.power_cycle(now);
        })
        .unwrap();
    let gateway = Gateway::start(&s.config);
    s.sub
        .wait_for("pulsegate/test/zh/status", Duration::from_secs(5), |m| {
            m.payload == "mode_mismatch"
        })
        .await
        .expect("status mode_mismatch");
    reading_after(&s.sub, "pulsegate/test/zh/di1", Instant::now()).await;
    tokio::time::sleep(Duration::from_millis(600)).await;
    assert!(
        s.sub.on("pulsegate/test/zh/di3").is_empty(),
        "the dead pair is not published as a channel that never moves"
    );
    assert!(
        gateway
            .log_text()
            .contains("mode words 0x0702 = 0x0002 and 0x0703 = 0x0000 disagree"),
        "the log says which words"
    );
    // Fixed, and the module restarted: the pair counts and the device is online again.
    s.plant
        .with_module("line1", 1, |m, now| {
            m.write_one(now, 0x0703, 0x0002).unwrap();
            m.power_cycle(now);
        })
        .unwrap();
    let fixed = Instant::now();
    s.sub
        .wait_for("pulsegate/test/zh/status", Duration::from_secs(5), |m| {
            m.at > fixed && m.payload == "online"
        })
        .await
        .expect("online again");
    reading_after(&s.sub, "pulsegate/test/zh/di3", fixed).await;
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_power_on_state_is_set_once_and_the_module_counts_by_itself_after_a_power_cut() {
    let s = setup(
        "zh-power-on",
        "[buses.line1.devices.zh]\nunit = 1\nmodel = \"zh-yx1600\"\nmodes = [2]\n",
        &[("line1", "zh", 1, "zh-yx1600", "200ms")],
        "[buses.line1.devices.zh.channels.di3]\npower_on = true\nrun = \"down\"\n\
         [buses.line1.devices.zh.channels.di1]\npower_on = true\n",
    )
    .await;
    let word = |a: u16| {
        s.plant
            .with_module("line1", 1, |m, now| m.read(now, a, 1).unwrap()[0])
            .unwrap()
    };
    let gateway = Gateway::start(&s.config);
    reading_after(&s.sub, "pulsegate/test/zh/di3", Instant::now()).await;
    // di1 is a quadrature pair (bit 1 kept): pAuto 1; di3 counts down: pAuto 2; di4 untouched.
    assert_eq!(word(0x0700), 0x0102);
    assert_eq!(word(0x0702), 0x0200);
    assert_eq!(word(0x0703), 0x0000);
    // The gateway is gone; the power is cut: the counters start by themselves.
    drop(gateway);
    s.plant
        .with_module("line1", 1, |m, now| m.power_cycle(now))
        .unwrap();
    assert!(running(&s.plant, 1, "di1") && running(&s.plant, 1, "di3"));
    assert!(
        !running(&s.plant, 1, "di4"),
        "not configured: stopped, as at the factory"
    );
    assert_eq!(word(0x1102), 0x00A3, "di3 counts down after power-up");
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_module_swapped_for_another_model_while_offline_is_refused_when_it_answers() {
    let s = setup(
        "swap",
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n\
         channels.a0 = { count = 5000 }\n",
        &[("line1", "meter", 1, "yl67", "100ms")],
        "",
    )
    .await;
    let _gateway = Gateway::start(&s.config);
    reading_after(&s.sub, "pulsegate/test/meter/a0", Instant::now()).await;
    // Someone takes the module out (the gateway sees it go offline) and puts a WJ157 in at the
    // same address.
    s.plant
        .with_module("line1", 1, |m, _| m.silent = true)
        .unwrap();
    s.sub
        .wait_for("pulsegate/test/meter/status", Duration::from_secs(5), |m| {
            m.payload == "offline"
        })
        .await
        .expect("offline while out");
    let swapped = swap_in_and_expect_wrong_model(&s, "wj157", &[1]).await;
    tokio::time::sleep(Duration::from_millis(500)).await;
    let after: Vec<Value> = s
        .sub
        .on("pulsegate/test/meter/a0")
        .into_iter()
        .filter(|m| m.at > swapped + Duration::from_millis(300))
        .map(|m| m.json())
        .collect();
    assert!(
        after.is_empty(),
        "no readings from the wrong model: {after:?}"
    );
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_sighup_after_a_profile_file_changed_restarts_the_bus_with_the_new_profile() {
    let s = setup(
        "profile-edit",
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n",
        &[("line1", "meter", 1, "mine", "100ms")],
        "",
    )
    .await;
    let dir = s.dir.join("profiles");
    std::fs::create_dir_all(&dir).unwrap();
    let yl67 = std::fs::read_to_string(concat!(env!("CARGO_MANIFEST_DIR"), "/profiles/yl67.toml"))
        .unwrap()
        .replace("model = \"yl67\"", "model = \"mine\"")
        .replace("aliases = [\"ibf67\"]\n", "");
    std::fs::write(dir.join("mine.toml"), &yl67).unwrap();
    let gateway = Gateway::start(&s.config);
    reading_after(&s.sub, "pulsegate/test/meter/a0", Instant::now()).await;
    std::fs::write(
        dir.join("mine.toml"),
        yl67.replace("name = \"a{}\"", "name = \"in{}\""),
    )
    .unwrap();
    gateway.signal("HUP");
    wait_log(&gateway, "config reloaded", 1).await;
    reading_after(&s.sub, "pulsegate/test/meter/in0", Instant::now()).await;
    assert!(
        gateway
            .log_text()
            .contains("bus stopped for the new config")
    );
    let _ = &s.broker;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn after_a_reset_the_identity_is_read_again_and_a_swapped_in_wrong_model_is_refused() {
    let s = setup(
        "swap-reset",
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"wj157\"\nmodes = [1]\n\
         channels.a0 = { count = 5000 }\n",
        &[("line1", "meter", 1, "wj157", "100ms")],
        "",
    )
    .await;
    let _gateway = Gateway::start(&s.config);
    reading_after(&s.sub, "pulsegate/test/meter/a0", Instant::now()).await;
    // A YL67 in DI mode answers every register the WJ157's counts use (32..35, 108, 144..147)
    // and its A0 reads 0: to the counters it looks like a module that restarted.
    swap_in_and_expect_wrong_model(&s, "yl67", &[1, 1, 1, 1]).await;
    let _ = (&s.broker, &s.dir);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_work_mode_change_keeps_the_state_of_channels_that_disappear_until_they_return() {
    let s = setup(
        "mode-change",
        "[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n",
        &[("line1", "meter", 1, "yl67", "100ms")],
        "",
    )
    .await;
    let gateway = Gateway::start(&s.config);
    let a0 = "pulsegate/test/meter/a0";
    reading_after(&s.sub, a0, Instant::now()).await;
    let from = count(&s.plant, 1, "a0");
    set_rate(&s.plant, 1, "a0", 400.0);
    wait_until("400 pulses", Duration::from_secs(10), || {
        count(&s.plant, 1, "a0") >= from + 400
    })
    .await;
    set_rate(&s.plant, 1, "a0", 0.0);
    let before = reading_after(&s.sub, a0, Instant::now() + Duration::from_millis(300)).await;
    let total = before["total"].as_i64().unwrap();
    assert!(total > 300, "{before}");
    // Encoder 0 switched to quadrature (register 0 = 0), effective after the module restarts.
    let switch = |mode: u16| {
        s.plant
            .with_module("line1", 1, |m, now| {
                m.write_one(now, 0, mode).unwrap();
                m.power_cycle(now);
            })
            .unwrap()
    };
    switch(0);
    let switched = Instant::now();
    reading_after(&s.sub, "pulsegate/test/meter/enc0", switched).await;
    saves_pass(&s.dir.join("bus-line1.json"), 2).await; // state flushes every 500 ms
    let saved = std::fs::read_to_string(s.dir.join("bus-line1.json")).unwrap();
    assert!(
        saved.contains("\"1/yl67/a0\""),
        "a0's state is kept: {saved}"
    );
    // Back to two counters: a0 continues from its total.
    switch(1);
    let from = count(&s.plant, 1, "a0");
    set_rate(&s.plant, 1, "a0", 400.0);
    wait_until("300 pulses", Duration::from_secs(10), || {
        count(&s.plant, 1, "a0") >= from + 300
    })
    .await;
    set_rate(&s.plant, 1, "a0", 0.0);
    let back = reading_after(&s.sub, a0, Instant::now() + Duration::from_millis(300)).await;
    let module_count = count(&s.plant, 1, "a0");
    assert_eq!(
        back["total"].as_i64().unwrap(),
        total + module_count,
        "the total continues: {back}"
    );
    drop(gateway);
    let _ = &s.broker;
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_paused_counter_is_left_paused_unless_configured_to_resume() {
    let s = setup(
        "zh-pause",
        "[buses.line1.devices.zh]\nunit = 1\nmodel = \"zh-yx1600\"\n",
        &[("line1", "zh", 1, "zh-yx1600", "200ms")],
        "[buses.line1.devices.zh.channels.di2]\nresume_paused = true\n",
    )
    .await;
    let _gateway = Gateway::start(&s.config);
    reading_after(&s.sub, "pulsegate/test/zh/di2", Instant::now()).await;
    set_rate(&s.plant, 1, "di1", 100.0);
    set_rate(&s.plant, 1, "di2", 100.0);
    wait_until("60 pulses each", Duration::from_secs(10), || {
        count(&s.plant, 1, "di1") >= 60 && count(&s.plant, 1, "di2") >= 60
    })
    .await;
    // Someone pauses both (0x0001: kept, not counting).
    s.plant
        .with_module("line1", 1, |m, now| {
            m.write_one(now, 0x1100, 0x0001).unwrap();
            m.write_one(now, 0x1101, 0x0001).unwrap();
        })
        .unwrap();
    wait_until("di2 resumed", Duration::from_secs(2), || {
        running(&s.plant, 1, "di2")
    })
    .await;
    tokio::time::sleep(Duration::from_millis(600)).await;
    assert!(!running(&s.plant, 1, "di1"), "di1 is left paused");
    set_rate(&s.plant, 1, "di2", 0.0);
    let last = reading_after(
        &s.sub,
        "pulsegate/test/zh/di2",
        Instant::now() + Duration::from_millis(400),
    )
    .await;
    assert_eq!(
        last["total"].as_i64().unwrap(),
        count(&s.plant, 1, "di2"),
        "a pause keeps the count: no reset"
    );
    let resets = readings(&s.sub, "pulsegate/test/zh/di2")
        .iter()
        .filter(|r| r["event"] == "reset")
        .count();
    assert_eq!(resets, 1, "only the first start");
    let _ = (&s.broker, &s.dir);
}

//! Edges a hostile or hurried world reaches (issue 23): response topics into the gateway's own
//! topics, a device undoing an inherited `min_interval`, scans and `commands = false`, reloads
//! and metric series, the state tools beside a running gateway, the spool's fallback, and a
//! broker that refuses MQTT 5.

use std::time::Duration;

use crate::support::{Broker, Gateway, Subscriber, gateway_toml, plant, temp_dir, write_config};

/// `[gateway] min_interval = "1s"`, a device with `publish = "poll"` and `min_interval = "0s"`:
/// that device publishes every poll, the other one still once a second.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_device_with_zero_min_interval_publishes_every_poll_under_a_paced_gateway() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.fast]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.paced]\nunit = 2\nmodel = \"yl67\"\n",
    )
    .await;
    let dir = temp_dir("zero-min-interval");
    let sub = Subscriber::start(broker.port, "pulsegate/test/+/enc0").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[
            ("line1", "fast", 1, "yl67", "200ms"),
            ("line1", "paced", 2, "yl67", "200ms"),
        ],
        "",
    )
    .replace("[gateway]\n", "[gateway]\nmin_interval = \"1s\"\n")
    .replace(
        "[buses.line1.devices.fast]\n",
        "[buses.line1.devices.fast]\npublish = \"poll\"\nmin_interval = \"0s\"\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let (fast, paced) = ("pulsegate/test/fast/enc0", "pulsegate/test/paced/enc0");
    sub.expect_any(fast, Duration::from_secs(10)).await;
    sub.clear();
    tokio::time::sleep(Duration::from_secs(4)).await;
    let (f, p) = (sub.on(fast).len(), sub.on(paced).len());
    // 20 polls in 4 s: every one published; the paced device at most one a second.
    assert!(f >= 15, "the 0s device publishes every poll: {f} in 4 s");
    assert!(
        (2..=5).contains(&p),
        "the inherited 1s still paces the other: {p}"
    );
}

/// Publishes a command as MQTT v5 with a response topic.
async fn command_v5(sub: &Subscriber, topic: &str, payload: &str, response_topic: &str) {
    let props = rumqttc::v5::mqttbytes::v5::PublishProperties {
        response_topic: Some(response_topic.into()),
        correlation_data: Some(bytes::Bytes::from_static(b"c")),
        ..Default::default()
    };
    sub.client
        .publish_with_properties(
            topic,
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            payload.to_string(),
            props,
        )
        .await
        .unwrap();
}

/// A command sender who may publish only command topics cannot, through the gateway's
/// response topic, put a result onto the gateway's status, a device's status or a reading
/// topic: each is refused on the default result topic and nothing lands there.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_response_topic_into_the_gateways_own_topics_gets_nothing_published_there() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let dir = temp_dir("response-topics");
    let sub = Subscriber::start(broker.port, "#").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        "",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let root = "pulsegate/test";
    sub.wait_for(
        &format!("{root}/meter/status"),
        Duration::from_secs(10),
        |m| m.payload == "online",
    )
    .await
    .expect("the device comes online");
    let targets = [
        (format!("{root}/ghost/enc0/cmd"), format!("{root}/status")),
        (
            format!("{root}/meter/enc0/cmd"),
            format!("{root}/meter/status"),
        ),
        (
            format!("{root}/meter/enc0/cmd"),
            format!("{root}/meter/enc1"),
        ),
    ];
    for (cmd, response) in &targets {
        command_v5(&sub, cmd, r#"{"op":"clear"}"#, response).await;
    }
    // A response topic outside the gateway's topics still gets its answer.
    command_v5(
        &sub,
        &format!("{root}/ghost/cmd"),
        r#"{"op":"clear_all"}"#,
        "replies/app/1",
    )
    .await;
    sub.wait_for("replies/app/1", Duration::from_secs(5), |m| {
        m.json()["error"] == "unknown_device"
    })
    .await
    .expect("an allowed response topic is answered");
    let refused = |topic: &str| {
        sub.on(topic)
            .iter()
            .filter(|m| m.json()["error"] == "bad_response_topic")
            .count()
    };
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while refused(&format!("{root}/meter/enc0/cmd/result")) < 2
        || refused(&format!("{root}/ghost/enc0/cmd/result")) < 1
    {
        assert!(
            tokio::time::Instant::now() < deadline,
            "each refusal answered on the default result topic: {:?}",
            sub.all()
                .iter()
                .filter(|m| m.topic.ends_with("/result"))
                .map(|m| (&m.topic, &m.payload))
                .collect::<Vec<_>>()
        );
        tokio::time::sleep(Duration::from_millis(50)).await;
    }
    tokio::time::sleep(Duration::from_millis(500)).await;
    for (_, response) in &targets {
        let results: Vec<String> = sub
            .on(response)
            .iter()
            .filter(|m| m.json().get("op").is_some() || m.json().get("error").is_some())
            .map(|m| m.payload.clone())
            .collect();
        assert!(results.is_empty(), "{response} got {results:?}");
    }
    let statuses: Vec<String> = sub
        .on(&format!("{root}/status"))
        .iter()
        .chain(sub.on(&format!("{root}/meter/status")).iter())
        .map(|m| m.payload.clone())
        .collect();
    assert!(
        statuses.iter().all(|p| p == "online"),
        "statuses stay online: {statuses:?}"
    );
    let log = _gw.log_text();
    assert!(log.contains("response topic refused"), "{log}");
}

/// Sixteen connections that send half a request and hold it (a slow-loris client) do not keep
/// a health probe out: `/healthz` answers 4 probes of 4, all within 2 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn held_half_written_requests_leave_healthz_answering() {
    use std::io::Write;
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let dir = temp_dir("slow-loris");
    let port = crate::support::free_port();
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        &format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n"),
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    crate::metrics::scrape_until(port, Duration::from_secs(10), "the endpoint is up", |t| {
        t.contains("pulsegate_mqtt_connected 1")
    })
    .await;
    let mut held = Vec::new();
    for _ in 0..16 {
        let mut s = std::net::TcpStream::connect(("127.0.0.1", port)).unwrap();
        s.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\nX-Slow: ")
            .unwrap();
        held.push(s);
    }
    tokio::time::sleep(Duration::from_millis(200)).await;
    let answered = tokio::task::spawn_blocking(move || {
        let start = std::time::Instant::now();
        let ok = (0..4)
            .filter(|_| crate::metrics::http_get(port, "/healthz").0 == 200)
            .count();
        (ok, start.elapsed())
    })
    .await
    .unwrap();
    assert_eq!(answered.0, 4, "probes answered 200: {answered:?}");
    assert!(answered.1 < Duration::from_secs(2), "{answered:?}");
    drop(held);
}

/// A device removed from the config and a SIGHUP: no series names it any more (it was exported
/// as up, so a dashboard would show a phantom device online).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_reload_that_removes_a_device_leaves_no_series_with_its_name() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.m1]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.m3]\nunit = 3\nmodel = \"yl67\"\n",
    )
    .await;
    let dir = temp_dir("reload-metrics");
    let port = crate::support::free_port();
    let metrics = format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n");
    let both = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[
            ("line1", "m1", 1, "yl67", "200ms"),
            ("line1", "m3", 3, "yl67", "200ms"),
        ],
        &metrics,
    );
    let gw = Gateway::start(&write_config(&dir, &both));
    let up = |d: &str| format!("pulsegate_device_up{{bus=\"line1\",device=\"{d}\"}}");
    let (up1, up3) = (up("m1"), up("m3"));
    crate::metrics::scrape_until(port, Duration::from_secs(10), "both devices up", |t| {
        crate::metrics::sample(t, &up1) == Some(1.0)
            && crate::metrics::sample(t, &up3) == Some(1.0)
            && t.contains("channel=\"enc0\",device=\"m3\"")
    })
    .await;
    let one = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "m1", 1, "yl67", "200ms")],
        &metrics,
    );
    write_config(&dir, &one);
    gw.signal("HUP");
    let text = crate::metrics::scrape_until(
        port,
        Duration::from_secs(10),
        "no series of m3 after the reload",
        |t| !t.contains("\"m3\""),
    )
    .await;
    assert_eq!(crate::metrics::sample(&text, &up1), Some(1.0), "{text}");
}

/// Runs `pulsegate <args> --config <config>`.
fn tool(args: &[&str], config: &std::path::Path) -> std::process::Output {
    std::process::Command::new(crate::support::bin())
        .args(args)
        .arg("--config")
        .arg(config)
        .output()
        .unwrap()
}

/// `state list` only reads: a state file of a newer format is named and left where it is (the
/// next gateway start must still find it, not a moved-aside copy).
#[test]
fn state_list_leaves_a_newer_format_file_untouched() {
    let dir = temp_dir("state-list-newer");
    let config = write_config(
        &dir,
        &format!(
            "[gateway]\nid = \"t\"\nstate_dir = {dir:?}\n[buses.line1]\nport = \"/dev/ttyS0\"\n\
             [buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n"
        ),
    );
    let file = dir.join("bus-line1.json");
    let newer = r#"{"version":999,"channels":{},"holes":{},"what":"comes next"}"#;
    std::fs::write(&file, newer).unwrap();
    for args in [
        &["state", "list"][..],
        &["state", "prune"],
        &["state", "prune", "--apply"],
    ] {
        let out = tool(args, &config);
        let err = String::from_utf8_lossy(&out.stderr);
        assert!(
            !out.status.success() && err.contains("newer"),
            "{args:?}: {err}"
        );
        assert_eq!(std::fs::read_to_string(&file).unwrap(), newer, "{args:?}");
        let names: Vec<String> = std::fs::read_dir(&dir)
            .unwrap()
            .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
            .collect();
        assert!(
            names.iter().all(|n| !n.contains(".bad-")),
            "{args:?} moved a file aside: {names:?}"
        );
    }
}

/// `state prune --apply` refuses while a gateway runs on the state directory, and works once it
/// has stopped.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn state_prune_apply_refuses_while_a_gateway_holds_the_state_directory() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let dir = temp_dir("state-prune-lock");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        "",
    );
    let config = write_config(&dir, &text);
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/meter/enc0", Duration::from_secs(10))
        .await;
    let out = tool(&["state", "prune", "--apply"], &config);
    let err = String::from_utf8_lossy(&out.stderr);
    assert!(
        !out.status.success() && err.contains("pulsegate.lock") && err.contains("stop it"),
        "{err}"
    );
    let dry = tool(&["state", "list"], &config);
    assert!(dry.status.success(), "listing needs no lock: {dry:?}");
    gw.terminate();
    let out = tool(&["state", "prune", "--apply"], &config);
    assert!(out.status.success(), "{out:?}");
}

/// A state directory whose spool cannot be made: the gateway spools in a fresh private
/// directory, never the old predictable `/tmp/pulsegate-spool-<pid>`, and says so in the log,
/// the metrics and `pulsegate check`; readings still flow.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unusable_spool_directory_falls_back_to_a_private_one_said_loudly() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let dir = temp_dir("spool-fallback");
    std::fs::write(dir.join("spool"), "a file where the spool directory goes").unwrap();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let port = crate::support::free_port();
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        &format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n"),
    );
    let config = write_config(&dir, &text);
    let check = tool(&["check"], &config);
    let said = String::from_utf8_lossy(&check.stdout);
    assert!(
        check.status.success() && said.contains("fresh private temporary directory"),
        "{said}"
    );
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/meter/enc0", Duration::from_secs(10))
        .await;
    crate::metrics::scrape_until(
        port,
        Duration::from_secs(5),
        "the fallback is exported",
        |t| crate::metrics::sample(t, "pulsegate_spool_private_fallback") == Some(1.0),
    )
    .await;
    let log = gw.log_text();
    assert!(
        log.contains("spooling in a fresh private directory"),
        "{log}"
    );
    let predictable = std::env::temp_dir().join(format!("pulsegate-spool-{}", gw.pid()));
    assert!(!predictable.exists(), "{}", predictable.display());
}

/// A broker that speaks only MQTT 3.1.1, as the old ones do: it reads the CONNECT and answers
/// any protocol level but 4 with the 3.1.1 CONNACK "unacceptable protocol version" (return code
/// 1, no properties), then closes. Returns its port; counts the connections it refused.
fn v311_only_broker() -> (u16, std::sync::Arc<std::sync::atomic::AtomicUsize>) {
    use std::io::{Read, Write};
    let listener = std::net::TcpListener::bind("127.0.0.1:0").unwrap();
    let port = listener.local_addr().unwrap().port();
    let refused = std::sync::Arc::new(std::sync::atomic::AtomicUsize::new(0));
    let counted = refused.clone();
    std::thread::spawn(move || {
        for conn in listener.incoming() {
            let Ok(mut c) = conn else { return };
            let _ = c.set_read_timeout(Some(Duration::from_secs(5)));
            // The whole CONNECT: fixed header, remaining length, body.
            let mut packet = vec![0u8; 1];
            let mut len = 0usize;
            for shift in [0, 7, 14, 21] {
                let mut b = [0u8; 1];
                if c.read_exact(&mut b).is_err() {
                    break;
                }
                packet.push(b[0]);
                len |= usize::from(b[0] & 0x7F) << shift;
                if b[0] & 0x80 == 0 {
                    break;
                }
            }
            let start = packet.len();
            packet.resize(start + len, 0);
            if c.read_exact(&mut packet[start..]).is_ok()
                && crate::protocol::protocol_level(&packet) != Some(4)
            {
                let _ = c.write_all(&[0x20, 0x02, 0x00, 0x01]);
                counted.fetch_add(1, std::sync::atomic::Ordering::Relaxed);
            }
        }
    });
    (port, refused)
}

/// Against a broker that refuses MQTT 5, the default (v5) gateway names the cause and the
/// setting that fixes it in the log (once, not as a timeout) and in the systemd status; both the
/// v5 answer (reason 0x84, from the 3.1.1 gate of `protocol.rs` in front of Mosquitto) and the
/// 3.1.1 answer of an old broker (return code 1, a stand-in listener) are understood.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_that_refuses_mqtt_5_is_named_with_the_setting_that_fixes_it() {
    let broker = Broker::start();
    let gate = crate::protocol::Gate::start(broker.port);
    let (old, refused) = v311_only_broker();
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let hint = "set mqtt.protocol = \"3.1.1\"";
    for (name, port) in [("refuses-v5-gate", gate.port), ("refuses-v5-old", old)] {
        let dir = temp_dir(name);
        let text = gateway_toml(
            &plant,
            port,
            &dir,
            &[("line1", "meter", 1, "yl67", "200ms")],
            "",
        );
        let sock_path = dir.join("notify.sock");
        let sock = std::os::unix::net::UnixDatagram::bind(&sock_path).unwrap();
        sock.set_read_timeout(Some(Duration::from_millis(200)))
            .unwrap();
        let gw = Gateway::start_with_env(
            &write_config(&dir, &text),
            &[("NOTIFY_SOCKET", sock_path.to_str().unwrap())],
        );
        // Five seconds: several attempts (one a second at first).
        let statuses = tokio::task::spawn_blocking(move || {
            let mut seen = Vec::new();
            let end = std::time::Instant::now() + Duration::from_secs(5);
            let mut buf = [0u8; 4096];
            while std::time::Instant::now() < end {
                if let Ok(n) = sock.recv(&mut buf) {
                    seen.push(String::from_utf8_lossy(&buf[..n]).into_owned());
                }
            }
            seen
        })
        .await
        .unwrap();
        let log = gw.log_text();
        let said = log
            .lines()
            .filter(|l| l.contains("refused the connection") && l.contains(hint))
            .count();
        assert_eq!(said, 1, "{name}: the cause and the fix, said once:\n{log}");
        assert!(log.contains("refuses MQTT 5"), "{name}:\n{log}");
        assert!(!log.contains("Timeout"), "{name}: not a timeout:\n{log}");
        assert!(
            statuses
                .iter()
                .any(|m| m.contains("STATUS=") && m.contains(hint)),
            "{name}: the systemd status names the fix: {statuses:?}"
        );
    }
    assert!(
        refused.load(std::sync::atomic::Ordering::Relaxed) >= 2,
        "the gateway kept trying the old broker"
    );
}

/// The README's example ACL, run as written (with this test's gateway id): the gateway, a
/// command sender (the MES), Home Assistant and a read-only dashboard each get what they need
/// (readings, command and scan results, discovery, replies on their own response topic), and a
/// user without command rights cannot command or forge a status.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_readme_acl_lets_each_user_do_its_part_and_nothing_else() {
    let readme = include_str!("../../README.md");
    let start = readme
        .find("# the gateway edge-01")
        .expect("the README's ACL example");
    let acl_text = &readme[start..start + readme[start..].find("```").unwrap()];
    let dir = temp_dir("readme-acl");
    let acl = dir.join("acl");
    std::fs::write(&acl, acl_text.replace("edge-01", "test")).unwrap();
    let passwords = dir.join("passwd");
    std::fs::write(&passwords, "").unwrap();
    for user in ["pulsegate-test", "mes", "homeassistant", "grafana"] {
        let ok = std::process::Command::new("mosquitto_passwd")
            .arg("-b")
            .arg(&passwords)
            .args([user, "pw"])
            .status()
            .expect("mosquitto_passwd");
        assert!(ok.success());
    }
    let port = crate::support::free_port();
    let _broker = Broker::start_with_config(
        port,
        &format!(
            "allow_anonymous false\npassword_file {}\nacl_file {}\n",
            passwords.display(),
            acl.display()
        ),
        port,
    );
    let plant = plant("[buses.line1.devices.meter]\nunit = 1\nmodel = \"yl67\"\n").await;
    let mes = Subscriber::start_with_login(port, "#", "mes", "pw").await;
    let ha = Subscriber::start_with_login(port, "#", "homeassistant", "pw").await;
    let grafana = Subscriber::start_with_login(port, "#", "grafana", "pw").await;
    let text = gateway_toml(
        &plant,
        port,
        &dir,
        &[("line1", "meter", 1, "yl67", "200ms")],
        "[homeassistant]\ndiscovery = true\n",
    )
    .replace(
        "[mqtt]\n",
        "[mqtt]\nusername = \"pulsegate-test\"\npassword = \"pw\"\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    let root = "pulsegate/test";
    for (who, sub) in [("mes", &mes), ("grafana", &grafana), ("homeassistant", &ha)] {
        assert!(
            sub.wait_for(
                &format!("{root}/meter/enc0"),
                Duration::from_secs(10),
                |_| true
            )
            .await
            .is_some(),
            "{who} reads the readings"
        );
    }
    let discovery = ha
        .all()
        .into_iter()
        .any(|m| m.topic.starts_with("homeassistant/") && m.topic.ends_with("/config"));
    assert!(discovery, "Home Assistant reads the discovery configs");

    // The MES clears, scans and gets a reply on its own response topic.
    command_v5(
        &mes,
        &format!("{root}/meter/enc0/cmd"),
        r#"{"op":"clear","id":"m1"}"#,
        "replies/mes/7",
    )
    .await;
    mes.client
        .publish(
            format!("{root}/bus/line1/scan"),
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            r#"{"units":"1-2","id":"s1"}"#,
        )
        .await
        .unwrap();
    let wait = Duration::from_secs(20);
    let ok = |m: &crate::support::Message| m.json()["ok"] == true;
    assert!(
        mes.wait_for(&format!("{root}/meter/enc0/cmd/result"), wait, ok)
            .await
            .is_some()
    );
    assert!(
        mes.wait_for("replies/mes/7", wait, ok).await.is_some(),
        "the reply"
    );
    assert!(
        mes.wait_for(&format!("{root}/bus/line1/scan/result"), wait, |m| m.json()
            ["id"]
            == "s1")
            .await
            .is_some(),
        "the scan's result"
    );
    // Home Assistant presses a clear button.
    ha.client
        .publish(
            format!("{root}/meter/cmd"),
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            r#"{"op":"clear_all","id":"h1"}"#,
        )
        .await
        .unwrap();
    assert!(
        ha.wait_for(&format!("{root}/meter/cmd/result"), wait, ok)
            .await
            .is_some()
    );

    // The dashboard cannot command, the MES cannot forge a status.
    grafana
        .client
        .publish(
            format!("{root}/meter/enc1/cmd"),
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            r#"{"op":"clear","id":"g1"}"#,
        )
        .await
        .unwrap();
    mes.client
        .publish(
            format!("{root}/status"),
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            "offline",
        )
        .await
        .unwrap();
    tokio::time::sleep(Duration::from_secs(1)).await;
    assert!(
        grafana
            .on(&format!("{root}/meter/enc1/cmd/result"))
            .is_empty()
    );
    assert!(
        grafana
            .on(&format!("{root}/status"))
            .iter()
            .all(|m| m.payload == "online"),
        "{:?}",
        grafana.on(&format!("{root}/status"))
    );
    assert!(
        grafana.on("replies/mes/7").is_empty(),
        "replies are the requester's"
    );
}

/// A scan over MQTT leaves a device with `commands = false` alone: its unit is neither asked nor
/// named in the result; a device that takes commands is listed as configured as before.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_scan_neither_asks_nor_names_a_device_with_commands_false() {
    let broker = Broker::start();
    let plant = plant(
        "[buses.line1.devices.open]\nunit = 1\nmodel = \"yl67\"\n\
         [buses.line1.devices.locked]\nunit = 2\nmodel = \"yl67\"\n",
    )
    .await;
    let dir = temp_dir("scan-commands-false");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = gateway_toml(
        &plant,
        broker.port,
        &dir,
        &[
            ("line1", "open", 1, "yl67", "200ms"),
            ("line1", "locked", 2, "yl67", "200ms"),
        ],
        "",
    )
    .replace(
        "[buses.line1.devices.locked]\n",
        "[buses.line1.devices.locked]\ncommands = false\n",
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    sub.expect_any("pulsegate/test/locked/enc0", Duration::from_secs(10))
        .await;
    sub.client
        .publish(
            "pulsegate/test/bus/line1/scan",
            rumqttc::v5::mqttbytes::QoS::AtLeastOnce,
            false,
            r#"{"units":"1-3","id":"s"}"#,
        )
        .await
        .unwrap();
    let result = sub
        .wait_for(
            "pulsegate/test/bus/line1/scan/result",
            Duration::from_secs(30),
            |m| m.json()["id"] == "s" && m.json().get("configured").is_some(),
        )
        .await
        .expect("the scan's result")
        .json();
    assert_eq!(result["configured"], serde_json::json!([1]), "{result}");
    assert_eq!(result["found"], serde_json::json!([]), "{result}");
}

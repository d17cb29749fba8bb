//! Edges a hostile or hurried world reaches over MQTT (issue 23): response topics into the
//! gateway's own topics, the documented ACL, scans and `commands = false`, a device undoing an
//! inherited `min_interval`, and a broker that refuses MQTT 5. The local ones (metrics endpoint,
//! state tools, spool fallback) are in `edges_local.rs`.

use std::time::Duration;

use crate::support::{
    Broker, Gateway, ONE_METER, Subscriber, gateway_toml, one_meter_toml, plant, temp_dir,
    write_config,
};

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
    tokio::time::sleep(Duration::from_secs(3)).await;
    let (f, p) = (sub.on(fast).len(), sub.on(paced).len());
    // 15 polls in 3 s: every one published; the paced device at most one a second.
    assert!(f >= 11, "the 0s device publishes every poll: {f} in 3 s");
    assert!(
        (2..=4).contains(&p),
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
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("response-topics");
    let sub = Subscriber::start(broker.port, "#").await;
    let text = one_meter_toml(&plant, broker.port, &dir, "");
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
    let plant = plant(ONE_METER).await;
    let hint = "set mqtt.protocol = \"3.1.1\"";
    for (name, port) in [("refuses-v5-gate", gate.port), ("refuses-v5-old", old)] {
        let dir = temp_dir(name);
        // Pinned to MQTT 5 (the default, "auto", would try 3.1.1 next: tests/integration/fleet.rs).
        let text = one_meter_toml(&plant, port, &dir, "").replacen(
            "[mqtt]\n",
            "[mqtt]\nprotocol = \"5\"\n",
            1,
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

/// The example ACL of docs/security.md, run as written (with this test's gateway id): the
/// gateway, a command sender (the MES), Home Assistant and a read-only dashboard each get what
/// they need
/// (readings, command and scan results, discovery, replies on their own response topic), and a
/// user without command rights cannot command or forge a status.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_documented_acl_lets_each_user_do_its_part_and_nothing_else() {
    let page = include_str!("../../docs/security.md");
    let start = page
        .find("# the gateway edge-01")
        .expect("the ACL example of docs/security.md");
    let acl_text = &page[start..start + page[start..].find("```").unwrap()];
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
    let plant = plant(ONE_METER).await;
    let mes = Subscriber::start_with_login(port, "#", "mes", "pw").await;
    let ha = Subscriber::start_with_login(port, "#", "homeassistant", "pw").await;
    let grafana = Subscriber::start_with_login(port, "#", "grafana", "pw").await;
    let text = one_meter_toml(&plant, port, &dir, "[homeassistant]\ndiscovery = true\n").replace(
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
    mes.send(
        &format!("{root}/bus/line1/scan"),
        r#"{"units":"1-2","id":"s1"}"#,
    )
    .await;
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
    ha.send(
        &format!("{root}/meter/cmd"),
        r#"{"op":"clear_all","id":"h1"}"#,
    )
    .await;
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
    mes.send(&format!("{root}/status"), "offline").await;
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
    sub.send(
        "pulsegate/test/bus/line1/scan",
        r#"{"units":"1-3","id":"s"}"#,
    )
    .await;
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

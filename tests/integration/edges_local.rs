//! Edges of issue 23 an operator meets on the gateway's own machine: the metrics endpoint
//! under held connections, metric series after a reload, the state tools beside a running
//! gateway, and the spool's fallback when the state directory cannot hold it.

use std::time::Duration;

use crate::support::{
    Broker, Gateway, ONE_METER, Subscriber, gateway_toml, one_meter_toml, plant, temp_dir,
    write_config,
};
/// Sixteen connections that send half a request and hold it (a slow-loris client) do not keep
/// a health probe out: `/healthz` answers 4 probes of 4, all within 2 s.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn held_half_written_requests_leave_healthz_answering() {
    use std::io::Write;
    let broker = Broker::start();
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("slow-loris");
    let port = crate::support::free_port();
    let text = one_meter_toml(
        &plant,
        broker.port,
        &dir,
        &format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n"),
    );
    let _gw = Gateway::start(&write_config(&dir, &text));
    crate::metrics::scrape_until(port, Duration::from_secs(10), "the endpoint is up", |t| {
        t.contains("pulsegate_mqtt_connected{output=\"json\"} 1")
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
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("state-prune-lock");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let text = one_meter_toml(&plant, broker.port, &dir, "");
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
    let plant = plant(ONE_METER).await;
    let dir = temp_dir("spool-fallback");
    std::fs::write(dir.join("spool"), "a file where the spool directory goes").unwrap();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let port = crate::support::free_port();
    let text = one_meter_toml(
        &plant,
        broker.port,
        &dir,
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
        |t| {
            crate::metrics::sample(t, "pulsegate_spool_private_fallback{output=\"json\"}")
                == Some(1.0)
        },
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

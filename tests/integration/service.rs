//! Running as a systemd service: sd-notify, the watchdog, SIGHUP reload, TLS, secrets.

use std::os::unix::net::UnixDatagram;
use std::process::{Command, Stdio};
use std::time::{Duration, Instant};

use crate::support::*;

/// Datagrams the gateway sent to the test's notify socket, with arrival times.
fn collect(sock: &UnixDatagram, for_: Duration) -> Vec<(Instant, String)> {
    let mut out = Vec::new();
    let end = Instant::now() + for_;
    let mut buf = [0u8; 4096];
    while Instant::now() < end {
        sock.set_read_timeout(Some(Duration::from_millis(100)))
            .unwrap();
        if let Ok(n) = sock.recv(&mut buf) {
            out.push((
                Instant::now(),
                String::from_utf8_lossy(&buf[..n]).to_string(),
            ));
        }
    }
    out
}

/// A child process killed when the test ends, even by a failed assertion.
struct Killed(std::process::Child);

impl std::ops::Deref for Killed {
    type Target = std::process::Child;
    fn deref(&self) -> &std::process::Child {
        &self.0
    }
}

impl std::ops::DerefMut for Killed {
    fn deref_mut(&mut self) -> &mut std::process::Child {
        &mut self.0
    }
}

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

fn start_notified(
    config: &std::path::Path,
    sock: &std::path::Path,
    extra_env: &[(&str, &str)],
) -> Killed {
    let mut cmd = Command::new(bin());
    cmd.args(["run", "--config"])
        .arg(config)
        .env("NOTIFY_SOCKET", sock)
        .env("WATCHDOG_USEC", "2000000")
        .stdout(Stdio::null())
        .stderr(std::fs::File::create(config.with_extension("log")).unwrap());
    for (k, v) in extra_env {
        cmd.env(k, v);
    }
    Killed(cmd.spawn().unwrap())
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn systemd_hears_ready_status_watchdog_and_stopping() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\n").await;
    let dir = temp_dir("notify");
    let config = write_config(
        &dir,
        &gateway_toml(
            &plant,
            broker.port,
            &dir,
            &[("line1", "d", 1, "yl67", "200ms")],
            "",
        ),
    );
    let sock_path = dir.join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    let mut child = start_notified(&config, &sock_path, &[]);
    let msgs = tokio::task::spawn_blocking(move || (collect(&sock, Duration::from_secs(4)), sock))
        .await
        .unwrap();
    let (msgs, sock) = msgs;
    let text: Vec<&str> = msgs.iter().map(|m| m.1.as_str()).collect();
    assert!(text.iter().any(|m| m.contains("READY=1")), "{text:?}");
    // The broker is up from the start: the ready status says so (it said "MQTT disconnected"
    // for up to a second after the connection, until the MQTT task's next beat).
    let ready = text.iter().find(|m| m.contains("READY=1")).unwrap();
    assert!(ready.contains("MQTT connected"), "{ready:?}");
    assert!(
        text.iter().any(|m| m.contains("STATUS=1/1 buses up")),
        "{text:?}"
    );
    let feeds = text.iter().filter(|m| m.contains("WATCHDOG=1")).count();
    assert!(
        feeds >= 4,
        "the watchdog is fed every half second or so: {feeds} in 4 s"
    );
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let msgs = tokio::task::spawn_blocking(move || collect(&sock, Duration::from_secs(2)))
        .await
        .unwrap();
    assert!(msgs.iter().any(|m| m.1.contains("STOPPING=1")), "{msgs:?}");
    assert!(child.wait().unwrap().success());
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_stuck_bus_loop_stops_the_watchdog() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\n[buses.line2.devices.e]\nunit = 1\nmodel = \"wj157\"\n").await;
    let dir = temp_dir("watchdog");
    let devices = [
        ("line1", "d", 1, "yl67", "200ms"),
        ("line2", "e", 1, "wj157", "200ms"),
    ];
    let config = write_config(&dir, &gateway_toml(&plant, broker.port, &dir, &devices, ""));
    let sock_path = dir.join("notify.sock");
    let sock = UnixDatagram::bind(&sock_path).unwrap();
    let started = Instant::now();
    let mut child = start_notified(
        &config,
        &sock_path,
        &[("PULSEGATE_TEST_STALL_BUS", "line2:2")],
    );
    let msgs = tokio::task::spawn_blocking(move || collect(&sock, Duration::from_secs(9)))
        .await
        .unwrap();
    let feeds: Vec<Duration> = msgs
        .iter()
        .filter(|m| m.1.contains("WATCHDOG=1"))
        .map(|m| m.0 - started)
        .collect();
    assert!(
        feeds.iter().any(|t| *t < Duration::from_secs(2)),
        "fed while healthy: {feeds:?}"
    );
    // Stuck at 2 s, stale after 3 s (half the 2 s period, at least 3 s): no feed after ~5.5 s.
    assert!(
        feeds.iter().all(|t| *t < Duration::from_millis(5500)),
        "still fed while a bus is stuck: {feeds:?}"
    );
    let _ = child.kill();
    let _ = child.wait();
    let log = std::fs::read_to_string(config.with_extension("log")).unwrap();
    assert!(log.contains("not feeding the watchdog"), "{log}");
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn sighup_reloads_changed_buses_keeps_the_others_and_refuses_a_bad_config() {
    let broker = Broker::start();
    let plant = plant("[buses.line1.devices.a]\nunit = 1\nmodel = \"yl67\"\nchannels.enc0 = { rate = 100.0 }\n[buses.line2.devices.b]\nunit = 1\nmodel = \"wj157\"\nchannels.enc0 = { rate = 100.0 }\n").await;
    let dir = temp_dir("reload");
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let devices = [
        ("line1", "a", 1, "yl67", "200ms"),
        ("line2", "b", 1, "wj157", "200ms"),
    ];
    let text = gateway_toml(&plant, broker.port, &dir, &devices, "");
    let config = write_config(&dir, &text);
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/b/enc0", Duration::from_secs(3))
        .await;
    tokio::time::sleep(Duration::from_secs(1)).await;

    // A bad config is refused; both buses go on.
    std::fs::write(&config, text.replace("poll = \"200ms\"", "poll = \"soon\"")).unwrap();
    gw.signal("HUP");
    tokio::time::sleep(Duration::from_millis(800)).await;
    assert!(
        gw.log_text().contains("new config refused"),
        "{}",
        gw.log_text()
    );

    // Only line2 changes.
    let changed = text.replacen(
        "[buses.line2.devices.b]\nunit = 1\nmodel = \"wj157\"\npoll = \"200ms\"",
        "[buses.line2.devices.b]\nunit = 1\nmodel = \"wj157\"\npoll = \"300ms\"",
        1,
    );
    assert_ne!(changed, text);
    std::fs::write(&config, &changed).unwrap();
    let t = Instant::now();
    gw.signal("HUP");
    assert!(
        sub.wait_for("pulsegate/test/b/enc0", Duration::from_secs(5), |m| m.at
            > t + Duration::from_millis(500))
            .await
            .is_some()
    );
    tokio::time::sleep(Duration::from_secs(1)).await;
    let log = gw.log_text();
    assert!(log.contains("config reloaded"), "{log}");
    assert_eq!(
        log.matches("bus started bus=line1").count(),
        1,
        "line1 kept running:\n{log}"
    );
    assert_eq!(
        log.matches("bus started bus=line2").count(),
        2,
        "line2 restarted:\n{log}"
    );
    // Counter state went on across the restart of line2: seq continues, total does not reset.
    for topic in ["pulsegate/test/a/enc0", "pulsegate/test/b/enc0"] {
        let r = readings(&sub, topic);
        let seqs: Vec<i64> = r.iter().map(|v| v["seq"].as_i64().unwrap()).collect();
        assert!(
            seqs.windows(2).all(|w| w[1] == w[0] + 1),
            "{topic}: {seqs:?}"
        );
        let totals: Vec<i64> = r.iter().map(|v| v["total"].as_i64().unwrap()).collect();
        assert!(
            totals.windows(2).all(|w| w[1] >= w[0]),
            "{topic}: {totals:?}"
        );
    }
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_gateway_publishes_over_tls_to_a_broker_with_a_test_ca() {
    let dir = temp_dir("tls");
    make_certs(&dir);
    let (plain, tls) = (free_port(), free_port());
    let mut broker = Broker::start_with_config(
        plain,
        &format!(
            "listener {tls} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\nallow_anonymous true\n",
            d = dir.display()
        ),
        tls,
    );
    let plant = plant("[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\n").await;
    let sub = Subscriber::start(plain, "pulsegate/test/#").await;
    let text = gateway_toml(
        &plant,
        tls,
        &dir,
        &[("line1", "d", 1, "yl67", "200ms")],
        &format!("[mqtt.tls]\nca_file = \"{}/ca.pem\"\n", dir.display()),
    );
    let config = write_config(&dir, &text);
    let _gw = Gateway::start(&config);
    let got = sub
        .wait_for("pulsegate/test/d/enc0", Duration::from_secs(5), |_| true)
        .await;
    assert!(got.is_some(), "readings arrive through the TLS listener");
    broker.stop();
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_mqtt_password_comes_from_a_systemd_credential_and_is_never_logged() {
    let dir = temp_dir("cred");
    let passwords = dir.join("passwd");
    std::fs::write(&passwords, "").unwrap();
    let ok = Command::new("mosquitto_passwd")
        .args(["-b"])
        .arg(&passwords)
        .args(["gw", "s3cret-Pa55"])
        .status()
        .expect("mosquitto_passwd");
    assert!(ok.success());
    let port = free_port();
    let mut broker = Broker::start_with_config(
        port,
        &format!("password_file {}\n", passwords.display()),
        port,
    );
    let creds = dir.join("creds");
    std::fs::create_dir_all(&creds).unwrap();
    std::fs::write(creds.join("mqtt-password"), "s3cret-Pa55\n").unwrap();
    let plant = plant("[buses.line1.devices.d]\nunit = 1\nmodel = \"yl67\"\n").await;
    let text = gateway_toml(
        &plant,
        port,
        &dir,
        &[("line1", "d", 1, "yl67", "200ms")],
        "",
    )
    .replace("[mqtt]\n", "[mqtt]\nusername = \"gw\"\n");
    let config = write_config(&dir, &text);
    let mut child = Killed(
        Command::new(bin())
            .args(["run", "--config"])
            .arg(&config)
            .env("CREDENTIALS_DIRECTORY", &creds)
            .env("RUST_LOG", "trace")
            .stdout(Stdio::null())
            .stderr(std::fs::File::create(dir.join("gw.log")).unwrap())
            .spawn()
            .unwrap(),
    );
    // The subscriber needs the password too.
    let sub = Subscriber::start_with_login(port, "pulsegate/test/#", "gw", "s3cret-Pa55").await;
    let got = sub
        .wait_for("pulsegate/test/d/enc0", Duration::from_secs(5), |_| true)
        .await;
    let _ = Command::new("kill")
        .args(["-TERM", &child.id().to_string()])
        .status();
    let _ = child.wait();
    broker.stop();
    assert!(got.is_some(), "the gateway logged in with the credential");
    let log = std::fs::read_to_string(dir.join("gw.log")).unwrap();
    assert!(
        !log.contains("s3cret-Pa55"),
        "the password appears in the log"
    );
}

//! Fleet operations against real brokers: the MQTT protocol found by itself (amqtt 0.12.1, a
//! broker that chokes on MQTT 5), failover between brokers, Sparkplug's node controls
//! (`Next Server`, `Reboot`), client certificates rotated under a broker that checks them.

use std::io::{BufRead, BufReader};
use std::path::Path;
use std::process::{Child, Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use serde_json::json;

use crate::sparkplug::{Host, of_type};
use crate::support::*;

/// One YL67 counting on `enc0`.
const ONE: &str = "[buses.line1.devices.m]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 200.0 }\n";
const DEVICES: [(&str, &str, u8, &str, &str); 1] = [("line1", "m", 1, "yl67", "100ms")];

/// A child process killed with this value.
struct Killed(Child);

impl Drop for Killed {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
    }
}

/// amqtt (the broker of amqtt 0.12.1, installed by scripts/test) on `port`.
fn amqtt(port: u16, dir: &Path) -> Killed {
    let conf = dir.join("amqtt.yaml");
    std::fs::write(
        &conf,
        format!(
            "listeners:\n  default:\n    type: tcp\n    bind: 127.0.0.1:{port}\nplugins:\n  amqtt.plugins.authentication.AnonymousAuthPlugin:\n    allow_anonymous: true\n"
        ),
    )
    .unwrap();
    let child = Command::new("amqtt")
        .arg("-c")
        .arg(&conf)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("amqtt (scripts/test installs amqtt 0.12.1)");
    let deadline = Instant::now() + Duration::from_secs(15);
    while std::net::TcpStream::connect(("127.0.0.1", port)).is_err() {
        assert!(Instant::now() < deadline, "amqtt did not listen on {port}");
        std::thread::sleep(Duration::from_millis(50));
    }
    Killed(child)
}

/// The lines `mosquitto_sub` prints for `filter` (topic and payload), an MQTT 3.1.1 client.
fn sub_311(port: u16, filter: &str) -> (Killed, Arc<Mutex<Vec<String>>>) {
    let mut child = Command::new("mosquitto_sub")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &port.to_string(),
            "-V",
            "mqttv311",
            "-v",
            "-t",
            filter,
        ])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("mosquitto_sub");
    let out = child.stdout.take().unwrap();
    let lines = Arc::new(Mutex::new(Vec::new()));
    let sink = lines.clone();
    std::thread::spawn(move || {
        for l in BufReader::new(out).lines().map_while(Result::ok) {
            sink.lock().unwrap().push(l);
        }
    });
    (Killed(child), lines)
}

/// With the default config (`protocol = "auto"`), a broker that takes MQTT 5's CONNECT and
/// never answers it (amqtt 0.12.1) gets MQTT 3.1.1 next: readings flow within 15 s and the log
/// says which protocol the broker speaks.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_broker_that_chokes_on_mqtt_5_gets_3_1_1_by_itself() {
    let dir = temp_dir("fleet-amqtt");
    let port = free_port();
    let _broker = amqtt(port, &dir);
    let (_sub, lines) = sub_311(port, "pulsegate/test/#");
    std::thread::sleep(Duration::from_millis(500));
    let plant = plant(ONE).await;
    let started = Instant::now();
    let gw = start_gateway(&plant, port, &dir, &DEVICES, "");
    let deadline = started + Duration::from_secs(15);
    loop {
        let readings = lines
            .lock()
            .unwrap()
            .iter()
            .filter(|l| l.starts_with("pulsegate/test/m/a0 "))
            .count();
        if readings >= 3 {
            break;
        }
        assert!(
            Instant::now() < deadline,
            "no readings over 3.1.1 within 15 s: {:?}",
            lines.lock().unwrap()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let log = gw.log_text();
    assert!(log.contains("trying MQTT 3.1.1 next"), "{log}");
    assert!(log.contains("the broker speaks MQTT 3.1.1"), "{log}");
}

/// Broker A dies with `hosts = [A, B]`: within `failover_after` plus 10 s the gateway publishes
/// on B, and a consumer of both brokers sums the deltas exactly (the spool carried what A did
/// not take over to B, in order). A reading A took but did not acknowledge before it died is
/// sent again to B: the consumer drops a repeated seq, as docs/operations.md tells consumers to.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_dead_broker_is_left_for_the_next_and_no_pulse_is_lost() {
    let (mut a, b) = (Broker::start(), Broker::start());
    let plant = plant(ONE).await;
    let dir = temp_dir("fleet-failover");
    let topic = "pulsegate/test/m/a0";
    let (sub_a, sub_b) = (
        Subscriber::start(a.port, topic).await,
        Subscriber::start(b.port, topic).await,
    );
    let extra = format!(
        "[outputs.json]\nkind = \"json\"\nhosts = [\"127.0.0.1:{}\", \"127.0.0.1:{}\"]\nfailover_after = \"5s\"\n",
        a.port, b.port
    );
    let gw = start_gateway(&plant, a.port, &dir, &DEVICES, &extra);
    sub_a
        .wait_more_than(topic, 3, Duration::from_secs(10))
        .await;
    a.stop();
    let gone = Instant::now();
    sub_b.expect_any(topic, Duration::from_secs(15)).await;
    assert!(
        gone.elapsed() < Duration::from_secs(15),
        "on B after {:?}",
        gone.elapsed()
    );
    let generated = stop_counting_and_gateway(&plant, gw, Duration::from_secs(2)).await;
    let mut all = readings(&sub_a, topic);
    all.extend(readings(&sub_b, topic));
    let first = all[0]["count"].as_i64().unwrap();
    assert_eq!(
        crate::hostile::consume(&all),
        generated - first,
        "summed deltas over both brokers"
    );
}

/// `Node Control/Next Server` moves a Sparkplug node to its next broker at once, where it is
/// born again (with the next bdSeq).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn next_server_moves_the_node_at_once() {
    let (a, b) = (Broker::start(), Broker::start());
    let (mut host_a, host_b) = (Host::start(a.port, false), Host::start(b.port, false));
    let plant = plant(ONE).await;
    let dir = temp_dir("fleet-next-server");
    let extra = format!(
        "[outputs.scada]\nkind = \"sparkplug\"\nhosts = [\"127.0.0.1:{}\", \"127.0.0.1:{}\"]\n[sparkplug]\ngroup_id = \"plant\"\n",
        a.port, b.port
    );
    let _gw = start_gateway(&plant, a.port, &dir, &DEVICES, &extra);
    host_a
        .wait(Duration::from_secs(15), "born on A", |l| {
            of_type(l, "DBIRTH").count() == 1
        })
        .await;
    let nbirth = of_type(&host_a.lines(), "NBIRTH").next().unwrap().clone();
    let names: Vec<&str> = nbirth["metrics"]
        .as_array()
        .unwrap()
        .iter()
        .filter_map(|m| m["name"].as_str())
        .collect();
    for control in [
        "Node Control/Rebirth",
        "Node Control/Reboot",
        "Node Control/Next Server",
    ] {
        assert!(
            names.contains(&control),
            "{control} in the NBIRTH: {names:?}"
        );
    }
    let asked = Instant::now();
    host_a.send(json!({"ncmd": "plant/test", "next_server": true}));
    host_b
        .wait(Duration::from_secs(5), "born on B", |l| {
            of_type(l, "DBIRTH").count() == 1 && of_type(l, "DDATA").count() >= 2
        })
        .await;
    assert!(asked.elapsed() < Duration::from_secs(5));
    host_a
        .wait(Duration::from_secs(5), "the NDEATH on A", |l| {
            of_type(l, "NDEATH").count() == 1
        })
        .await;
}

/// `Node Control/Reboot`: an orderly stop (the state saved) and an exit status the service
/// restarts on (75: not 0, not 2).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn reboot_stops_cleanly_with_a_status_the_service_restarts_on() {
    let broker = Broker::start();
    let mut host = Host::start(broker.port, false);
    let plant = plant(ONE).await;
    let dir = temp_dir("fleet-reboot");
    let extra = "[outputs.scada]\nkind = \"sparkplug\"\n[sparkplug]\ngroup_id = \"plant\"\n";
    let mut gw = start_gateway(&plant, broker.port, &dir, &DEVICES, extra);
    host.wait(Duration::from_secs(15), "data", |l| {
        of_type(l, "DDATA").count() >= 5
    })
    .await;
    host.send(json!({"ncmd": "plant/test", "reboot": true}));
    let status = gw
        .wait_exit(Duration::from_secs(15))
        .expect("the gateway stopped by itself");
    assert_eq!(status.code(), Some(75), "{status:?}");
    let log = gw.log_text();
    assert!(log.contains("rebooting as asked"), "{log}");
    let saved = std::fs::read_to_string(dir.join("bus-line1.json")).expect("the bus's state saved");
    assert!(saved.contains("a0"), "{saved}");
}

/// The certificate's notAfter, seconds since the epoch, as openssl reads it.
fn not_after(pem: &Path) -> i64 {
    let out = Command::new("openssl")
        .args(["x509", "-noout", "-enddate", "-dateopt", "iso_8601", "-in"])
        .arg(pem)
        .output()
        .unwrap();
    let text = String::from_utf8_lossy(&out.stdout);
    let when = text.trim().trim_start_matches("notAfter=");
    let t = humantime::parse_rfc3339_weak(when.trim_end_matches('Z')).unwrap();
    t.duration_since(std::time::UNIX_EPOCH).unwrap().as_secs() as i64
}

/// Client certificate files replaced under a broker that checks them: the next connection
/// (the broker restarted) shows the new identity, with no gateway restart; the expiry metric is
/// the certificate's notAfter, and a certificate that expires within 30 days is warned of.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn client_certificates_rotate_without_a_restart() {
    let dir = temp_dir("fleet-certs");
    std::fs::set_permissions(&dir, std::os::unix::fs::PermissionsExt::from_mode(0o755)).unwrap();
    make_certs(&dir);
    client_certificate(&dir, "gw-old", 10, "client");
    client_certificate(&dir, "gw-new", 20, "next");
    let (plain, tls, http) = (free_port(), free_port(), free_port());
    let log = dir.join("mosquitto.log");
    std::fs::write(&log, "").unwrap();
    std::fs::set_permissions(&log, std::os::unix::fs::PermissionsExt::from_mode(0o666)).unwrap();
    let broker_conf = format!(
        "log_dest file {l}\nlog_type all\nlistener {tls} 127.0.0.1\ncafile {d}/ca.pem\ncertfile {d}/server.pem\nkeyfile {d}/server.key\nrequire_certificate true\nuse_identity_as_username true\nallow_anonymous true\n",
        l = log.display(),
        d = dir.display()
    );
    let mut broker = Broker::start_with_config(plain, &broker_conf, tls);
    let plant = plant(ONE).await;
    let extra = format!(
        "[mqtt.tls]\nca_file = \"{d}/ca.pem\"\ncert_file = \"{d}/client.pem\"\nkey_file = \"{d}/client.key\"\n[metrics]\nlisten = \"127.0.0.1:{http}\"\n",
        d = dir.display()
    );
    let gw = start_gateway(&plant, tls, &dir, &DEVICES, &extra);
    let said = |who: &str| {
        std::fs::read_to_string(&log)
            .unwrap_or_default()
            .contains(&format!("u'{who}'"))
    };
    wait_until(Duration::from_secs(15), "connected as gw-old", || {
        said("gw-old")
    })
    .await;
    let series = format!(
        "pulsegate_tls_certificate_expiry_timestamp_seconds{{file=\"{}/client.pem\",output=\"json\"}}",
        dir.display()
    );
    let text =
        crate::metrics::scrape_until(http, Duration::from_secs(10), "the expiry metric", |t| {
            crate::metrics::sample(t, &series).is_some()
        })
        .await;
    assert_eq!(
        crate::metrics::sample(&text, &series),
        Some(not_after(&dir.join("client.pem")) as f64)
    );
    assert!(
        gw.log_text().contains("expires in"),
        "a certificate of 10 days is warned of"
    );
    // Rotate: the new files replace the old ones, then the broker restarts (a next connection).
    std::fs::copy(dir.join("next.key"), dir.join("client.key.new")).unwrap();
    std::fs::copy(dir.join("next.pem"), dir.join("client.pem.new")).unwrap();
    std::fs::rename(dir.join("client.key.new"), dir.join("client.key")).unwrap();
    std::fs::rename(dir.join("client.pem.new"), dir.join("client.pem")).unwrap();
    broker.stop();
    let _broker = Broker::start_with_config(plain, &broker_conf, tls);
    wait_until(Duration::from_secs(20), "connected as gw-new", || {
        said("gw-new")
    })
    .await;
    let text = crate::metrics::scrape_until(http, Duration::from_secs(10), "the new expiry", |t| {
        crate::metrics::sample(t, &series) == Some(not_after(&dir.join("client.pem")) as f64)
    })
    .await;
    assert!(text.contains("pulsegate_tls_certificate_expiry_timestamp_seconds"));
    assert!(
        gw.log_text().contains("TLS files changed"),
        "{}",
        gw.log_text()
    );
}

async fn wait_until(timeout: Duration, what: &str, mut done: impl FnMut() -> bool) {
    let deadline = Instant::now() + timeout;
    while !done() {
        assert!(Instant::now() < deadline, "{what} within {timeout:?}");
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// Two YL67 counting on line1; the first config polls only `m`.
const TWO: &str = "[buses.line1.devices.m]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 200.0 }\n[buses.line1.devices.n]\nunit = 2\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 100.0 }\n";

/// The config text of a gateway on `port` polling `devices`, taking pushed configs.
fn remote_toml(
    plant: &pulsegate::sim::Plant,
    port: u16,
    dir: &Path,
    devices: &[(&str, &str, u8, &str, &str)],
    http: u16,
) -> String {
    let extra = format!(
        "[remote]\nconfig = true\ngrace = \"5s\"\n[metrics]\nlisten = \"127.0.0.1:{http}\"\n"
    );
    gateway_toml(plant, port, dir, devices, &extra)
}

/// Publishes a push of `toml` with `id` on the gateway's config topic.
async fn push(sub: &Subscriber, id: &str, toml: &str) {
    let body = json!({"id": id, "toml": toml}).to_string();
    sub.send("pulsegate/test/config/set", body).await;
}

/// The results of the push `id`, as they came.
fn results(sub: &Subscriber, id: &str) -> Vec<serde_json::Value> {
    sub.on("pulsegate/test/config/result")
        .iter()
        .map(|m| m.json())
        .filter(|v| v["id"] == id)
        .collect()
}

async fn result_with(
    sub: &Subscriber,
    id: &str,
    status: &str,
    within: Duration,
) -> serde_json::Value {
    let deadline = Instant::now() + within;
    loop {
        if let Some(r) = results(sub, id).into_iter().find(|r| r["status"] == status) {
            return r;
        }
        assert!(
            Instant::now() < deadline,
            "no {status} result for {id} within {within:?}: {:?}",
            results(sub, id)
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

/// A pushed config that adds a device: applied (the file on disk replaced, the previous kept
/// beside it), the new device publishes, the config hash moves in `<root>/gateway` and in the
/// metric; after its grace period it is kept. One with an unknown key is refused naming the
/// key, and nothing changes.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pushed_config_is_checked_applied_shown_and_kept() {
    let broker = Broker::start();
    let plant = plant(TWO).await;
    let dir = temp_dir("fleet-push");
    let http = free_port();
    let one = [("line1", "m", 1, "yl67", "100ms")];
    let both = [
        ("line1", "m", 1, "yl67", "100ms"),
        ("line1", "n", 2, "yl67", "100ms"),
    ];
    let first = remote_toml(&plant, broker.port, &dir, &one, http);
    let config = write_config(&dir, &first);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;
    let marker = |sub: &Subscriber| {
        sub.on("pulsegate/test/gateway")
            .last()
            .map(|m| m.json()["config"].clone())
    };
    let hash_before = marker(&sub).expect("the boot marker");

    let bad = first.replacen("[gateway]\n", "[gateway]\nnope = 1\n", 1);
    push(&sub, "bad-1", &bad).await;
    let refused = result_with(&sub, "bad-1", "refused", Duration::from_secs(5)).await;
    assert_eq!(refused["error"], "bad_config", "{refused}");
    assert!(
        refused["message"]
            .as_str()
            .unwrap()
            .contains("gateway.nope"),
        "{refused}"
    );
    assert_eq!(
        std::fs::read_to_string(&config).unwrap(),
        first,
        "the file is untouched"
    );

    // Credentials change only with [remote] security = true.
    let other_user = first.replacen("[mqtt]\n", "[mqtt]\nusername = \"someone\"\n", 1);
    push(&sub, "creds", &other_user).await;
    let forbidden = result_with(&sub, "creds", "refused", Duration::from_secs(5)).await;
    assert_eq!(forbidden["error"], "forbidden", "{forbidden}");
    assert!(
        forbidden["message"]
            .as_str()
            .unwrap()
            .contains("mqtt: credentials")
    );
    assert_eq!(std::fs::read_to_string(&config).unwrap(), first);

    let second = remote_toml(&plant, broker.port, &dir, &both, http);
    push(&sub, "add-n", &second).await;
    let applied = result_with(&sub, "add-n", "applied", Duration::from_secs(10)).await;
    assert_eq!(applied["ok"], true, "{applied}");
    assert_eq!(
        std::fs::read_to_string(&config).unwrap(),
        second,
        "the file replaced"
    );
    let previous = dir.join("pulsegate.toml.previous");
    assert_eq!(
        std::fs::read_to_string(previous).unwrap(),
        first,
        "the previous kept beside it"
    );
    sub.expect_any("pulsegate/test/n/a0", Duration::from_secs(10))
        .await;
    let hash_after = applied["config"].clone();
    assert_ne!(hash_after, hash_before);
    let series = format!("pulsegate_config_info{{hash={hash_after}}}");
    crate::metrics::scrape_until(http, Duration::from_secs(5), "the new hash", |t| {
        crate::metrics::sample(t, &series) == Some(1.0)
    })
    .await;
    sub.wait_for("pulsegate/test/gateway", Duration::from_secs(5), |m| {
        m.json()["config"] == hash_after
    })
    .await
    .expect("the boot marker says the new hash");
    let kept = result_with(&sub, "add-n", "kept", Duration::from_secs(15)).await;
    assert_eq!(kept["ok"], true);
    drop(gw);
}

/// A pushed config pointing at a dead broker: the rebuilt output cannot connect, so within its
/// grace period plus 30 s the previous file is back and in force, the result says
/// `rolled_back` with the reason, and a consumer sums every pulse across it.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pushed_config_at_a_dead_broker_is_rolled_back_and_no_pulse_is_lost() {
    let broker = Broker::start();
    let plant = plant(ONE).await;
    let dir = temp_dir("fleet-rollback");
    let http = free_port();
    // Moving the broker moves where the credentials go: only a signed push may.
    let (key, public) = crate::pushes::openssl_key(&dir, "signer");
    let trusted = format!("[remote]\ntrusted_keys = [\"{public}\"]\n");
    let first =
        remote_toml(&plant, broker.port, &dir, &DEVICES, http).replacen("[remote]\n", &trusted, 1);
    let config = write_config(&dir, &first);
    let topic = "pulsegate/test/m/a0";
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&config);
    sub.expect_any(topic, Duration::from_secs(10)).await;
    let dead =
        remote_toml(&plant, free_port(), &dir, &DEVICES, http).replacen("[remote]\n", &trusted, 1);
    let signed = crate::pushes::openssl_signed(&key, "test", "dead-broker", 1, &dead);
    sub.send("pulsegate/test/config/set", signed).await;
    // Its progress result ("applied") is said on the connection to the dead broker: only the
    // final one, after the rollback, can arrive.
    let pushed = Instant::now();
    let back = result_with(
        &sub,
        "dead-broker",
        "rolled_back",
        Duration::from_secs(5 + 30),
    )
    .await;
    assert!(pushed.elapsed() < Duration::from_secs(35));
    assert_eq!(back["error"], "rolled_back", "{back}");
    assert!(
        back["message"].as_str().unwrap().contains("not up"),
        "{back}"
    );
    assert_eq!(
        std::fs::read_to_string(&config).unwrap(),
        first,
        "the previous file is back"
    );
    let generated = stop_counting_and_gateway(&plant, gw, Duration::from_secs(2)).await;
    let all = readings(&sub, topic);
    let first_count = all[0]["count"].as_i64().unwrap();
    assert_eq!(
        crate::hostile::consume(&all),
        generated - first_count,
        "summed deltas across the rollback"
    );
}

/// A pushed config that only a new start applies (`[gateway]`): the gateway starts itself again
/// on it (same process id) and its watch goes on there, to `kept`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_pushed_config_of_the_gateway_section_restarts_it_and_is_watched_after() {
    let broker = Broker::start();
    let plant = plant(ONE).await;
    let dir = temp_dir("fleet-push-restart");
    let http = free_port();
    let first = remote_toml(&plant, broker.port, &dir, &DEVICES, http);
    let config = write_config(&dir, &first);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;
    let slower = first.replacen("state_flush = \"500ms\"", "state_flush = \"2s\"", 1);
    assert_ne!(slower, first);
    push(&sub, "flush-2s", &slower).await;
    let kept = result_with(&sub, "flush-2s", "kept", Duration::from_secs(30)).await;
    assert_eq!(kept["ok"], true, "{kept}");
    let log = gw.log_text();
    assert!(
        log.contains("starting again for the pushed config"),
        "{log}"
    );
    assert!(log.contains("watched for"), "{log}");
    assert_eq!(std::fs::read_to_string(&config).unwrap(), slower);
}

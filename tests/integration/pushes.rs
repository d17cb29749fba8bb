//! Pushed configs tried as an attacker on the plant network and as an unlucky operator would:
//! against the gateway binary, a real Mosquitto, a fake broker that keeps every byte a client
//! sends it, keys made and pushes signed by openssl (another Ed25519 implementation than ours).
//!
//! These wait in real time: the gateway is a separate process that starts itself again (exec)
//! and is killed with SIGKILL, and the grace periods are those of that process's clock.

use std::io::{Read, Write};
use std::net::TcpListener;
use std::path::{Path, PathBuf};
use std::process::Command;
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use base64::Engine as _;
use serde_json::json;

use crate::support::*;

/// One YL67 counting on `a0`, and a second one the first config does not poll.
const TWO: &str = "[buses.line1.devices.m]\nunit = 1\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 200.0 }\n[buses.line1.devices.n]\nunit = 2\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 100.0 }\n";
const M: (&str, &str, u8, &str, &str) = ("line1", "m", 1, "yl67", "100ms");
const TOKEN: &str = "operators-token-0123456789";

/// A listener that accepts every connection and keeps every byte sent to it.
struct FakeBroker {
    port: u16,
    bytes: Arc<Mutex<Vec<u8>>>,
    connections: Arc<Mutex<usize>>,
}

impl FakeBroker {
    fn start() -> FakeBroker {
        let listener = TcpListener::bind("127.0.0.1:0").unwrap();
        let port = listener.local_addr().unwrap().port();
        let bytes = Arc::new(Mutex::new(Vec::new()));
        let connections = Arc::new(Mutex::new(0));
        let (b, c) = (bytes.clone(), connections.clone());
        std::thread::spawn(move || {
            for s in listener.incoming() {
                let Ok(mut s) = s else { return };
                *c.lock().unwrap() += 1;
                let b = b.clone();
                std::thread::spawn(move || {
                    let mut buf = [0u8; 4096];
                    while let Ok(n) = s.read(&mut buf) {
                        if n == 0 {
                            return;
                        }
                        b.lock().unwrap().extend_from_slice(&buf[..n]);
                    }
                });
            }
        });
        FakeBroker {
            port,
            bytes,
            connections,
        }
    }

    fn saw(&self, needle: &[u8]) -> bool {
        let b = self.bytes.lock().unwrap();
        b.windows(needle.len()).any(|w| w == needle)
    }
}

/// The config of a gateway on `broker` polling `devices`, taking pushes, its status page on
/// `http` with [`TOKEN`]; `remote` adds keys to `[remote]`, `mqtt` to `[mqtt]`.
fn config_text(
    plant: &pulsegate::sim::Plant,
    broker: u16,
    dir: &Path,
    devices: &[(&str, &str, u8, &str, &str)],
    (http, remote, mqtt): (u16, &str, &str),
) -> String {
    let extra = format!(
        "[remote]\nconfig = true\ngrace = \"5s\"\n{remote}[metrics]\nlisten = \"127.0.0.1:{http}\"\ntoken = \"{TOKEN}\"\n"
    );
    gateway_toml(plant, broker, dir, devices, &extra).replacen(
        "[mqtt]\n",
        &format!("[mqtt]\n{mqtt}"),
        1,
    )
}

async fn publish(sub: &Subscriber, payload: String) {
    sub.send("pulsegate/test/config/set", payload).await;
}

fn unsigned(id: &str, toml: &str) -> String {
    json!({"id": id, "toml": toml}).to_string()
}

/// The final result of push `id` (`kept`, `rolled_back` or `refused`), waiting for it.
async fn final_result(sub: &Subscriber, id: &str, within: Duration) -> serde_json::Value {
    let deadline = Instant::now() + within;
    loop {
        let finals = finals(sub, id);
        if let Some(r) = finals.first() {
            return r.clone();
        }
        assert!(
            Instant::now() < deadline,
            "no final result for {id} within {within:?}: {:?}",
            sub.on("pulsegate/test/config/result")
                .iter()
                .map(|m| m.json())
                .collect::<Vec<_>>()
        );
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
}

fn finals(sub: &Subscriber, id: &str) -> Vec<serde_json::Value> {
    sub.on("pulsegate/test/config/result")
        .iter()
        .map(|m| m.json())
        .filter(|v| v["id"] == id && v["status"] != "applied")
        .collect()
}

async fn refused(sub: &Subscriber, id: &str, error: &str) -> serde_json::Value {
    let r = final_result(sub, id, Duration::from_secs(30)).await;
    assert_eq!(
        (r["status"].as_str(), r["error"].as_str()),
        (Some("refused"), Some(error)),
        "{r}"
    );
    r
}

/// `GET path` with the bearer token; the status, 0 when nothing listens.
fn get(port: u16, path: &str, token: &str) -> u16 {
    let Ok(mut s) = std::net::TcpStream::connect(("127.0.0.1", port)) else {
        return 0;
    };
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let _ = write!(
        s,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nAuthorization: Bearer {token}\r\nConnection: close\r\n\r\n"
    );
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    text.split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0)
}

/// An Ed25519 key made by openssl, and its raw public key in base64.
pub(crate) fn openssl_key(dir: &Path, name: &str) -> (PathBuf, String) {
    let pem = dir.join(format!("{name}.pem"));
    let ok = Command::new("openssl")
        .args(["genpkey", "-algorithm", "ed25519", "-out"])
        .arg(&pem)
        .status()
        .unwrap();
    assert!(ok.success());
    let der = Command::new("openssl")
        .args(["pkey", "-pubout", "-outform", "DER", "-in"])
        .arg(&pem)
        .output()
        .unwrap()
        .stdout;
    let raw = &der[der.len() - 32..];
    (pem, base64::engine::general_purpose::STANDARD.encode(raw))
}

/// A push signed by openssl over the documented bytes (docs/operations.md).
pub(crate) fn openssl_signed(
    pem: &Path,
    gateway: &str,
    id: &str,
    serial: u64,
    toml: &str,
) -> String {
    let msg = pem.with_extension(format!("{id}.msg"));
    std::fs::write(
        &msg,
        format!("pulsegate-config-v1\n{gateway}\n{id}\n{serial}\n{toml}"),
    )
    .unwrap();
    let out = Command::new("openssl")
        .args(["pkeyutl", "-sign", "-rawin", "-inkey"])
        .arg(pem)
        .arg("-in")
        .arg(&msg)
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "{}",
        String::from_utf8_lossy(&out.stderr)
    );
    let signature = base64::engine::general_purpose::STANDARD.encode(out.stdout);
    json!({"id": id, "serial": serial, "toml": toml, "signature": signature}).to_string()
}

/// Without trusted keys, a push may not move anything trust rests on. Moving `[mqtt] port` to
/// a listener of the attacker's is refused, and that listener never sees a byte (the password
/// the gateway read from a file included); so are pushes of `metrics.listen`, `client_id`,
/// `state_dir` and a new output with a host of its own, each naming what it touched, the file
/// unchanged.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn an_unsigned_push_moves_no_trust_and_the_password_stays_home() {
    let broker = Broker::start();
    let fake = FakeBroker::start();
    let plant = plant(TWO).await;
    let dir = temp_dir("push-unsigned");
    let password = "s3cret-from-a-file";
    std::fs::write(dir.join("mqtt-password"), password).unwrap();
    let mqtt = format!(
        "username = \"gw\"\npassword_file = {:?}\n",
        dir.join("mqtt-password")
    );
    let http = free_port();
    let first = config_text(&plant, broker.port, &dir, &[M], (http, "", &mqtt));
    let config = write_config(&dir, &first);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;

    let port_line = format!("port = {}\n", broker.port);
    let other_state = dir.join("elsewhere");
    let cases = [
        (
            "port",
            first.replacen(&port_line, &format!("port = {}\n", fake.port), 1),
            "mqtt: host, port",
        ),
        (
            "listen",
            first.replacen(&format!("127.0.0.1:{http}"), "0.0.0.0:19464", 1),
            "[metrics]",
        ),
        (
            "client",
            first.replacen("[mqtt]\n", "[mqtt]\nclient_id = \"pulsegate-plant-9\"\n", 1),
            "mqtt: client_id",
        ),
        (
            "state",
            first.replacen(
                &format!("state_dir = {dir:?}"),
                &format!("state_dir = {other_state:?}"),
                1,
            ),
            "gateway.state_dir",
        ),
        (
            "output",
            format!(
                "{first}[outputs.leak]\nkind = \"json\"\nhost = \"127.0.0.1\"\nport = {}\n",
                fake.port
            ),
            "outputs.leak: host",
        ),
    ];
    for (id, toml, named) in &cases {
        assert_ne!(toml, &first, "{id} changes something");
        publish(&sub, unsigned(id, toml)).await;
        let r = refused(&sub, id, "forbidden").await;
        assert!(r["message"].as_str().unwrap().contains(named), "{id}: {r}");
        assert_eq!(
            std::fs::read_to_string(&config).unwrap(),
            first,
            "{id}: the file unchanged"
        );
    }
    // Every push is answered by now; give a connection to the fake broker time to show up.
    tokio::time::sleep(Duration::from_secs(2)).await;
    assert_eq!(
        *fake.connections.lock().unwrap(),
        0,
        "nothing connected to the attacker's port"
    );
    assert!(!fake.saw(password.as_bytes()), "the password never left");
    assert!(
        std::fs::read_dir(&dir)
            .unwrap()
            .all(|e| !e.unwrap().path().ends_with("elsewhere"))
    );
}

/// With a trusted key, only pushes signed by it for this gateway with a new serial are taken:
/// unsigned, untrusted, for another gateway, a changed byte and a replay are each refused. A
/// signed push moves the status page to another port (the process starts again on it) and is
/// kept; a second one moves it again with another token and silences a device: it is rolled
/// back, the listener of before answers with its token, the new one is closed, and the hash
/// said is the one of the config that runs again.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn only_signed_pushes_move_trust_and_a_rollback_undoes_all_of_it() {
    let broker = Broker::start();
    let plant = plant(TWO).await;
    let dir = temp_dir("push-signed");
    let (key, public) = openssl_key(&dir, "signer");
    let (stranger, _) = openssl_key(&dir, "stranger");
    let remote = format!("trusted_keys = [\"{public}\"]\n");
    let (http1, http2, http3) = (free_port(), free_port(), free_port());
    let text = |http: u16| config_text(&plant, broker.port, &dir, &[M], (http, &remote, ""));
    let first = text(http1);
    let config = write_config(&dir, &first);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;

    let moved = text(http2);
    publish(&sub, unsigned("plain", &moved)).await;
    refused(&sub, "plain", "unsigned").await;
    publish(
        &sub,
        openssl_signed(&stranger, "test", "stranger", 1, &moved),
    )
    .await;
    refused(&sub, "stranger", "bad_signature").await;
    publish(
        &sub,
        openssl_signed(&key, "other-gateway", "elsewhere", 1, &moved),
    )
    .await;
    refused(&sub, "elsewhere", "bad_signature").await;
    let mut tampered: serde_json::Value =
        serde_json::from_str(&openssl_signed(&key, "test", "tampered", 1, &moved)).unwrap();
    tampered["toml"] = moved.replacen("grace = \"5s\"", "grace = \"6s\"", 1).into();
    publish(&sub, tampered.to_string()).await;
    refused(&sub, "tampered", "bad_signature").await;
    assert_eq!(std::fs::read_to_string(&config).unwrap(), first);

    let good = openssl_signed(&key, "test", "move-page", 1, &moved);
    publish(&sub, good.clone()).await;
    let kept = final_result(&sub, "move-page", Duration::from_secs(40)).await;
    assert_eq!(kept["status"], "kept", "{kept}");
    assert_eq!(get(http2, "/api/v1/status", TOKEN), 200, "the new listener");
    assert_eq!(get(http1, "/healthz", TOKEN), 0, "the old one closed");
    let hash_kept = kept["config"].clone();

    publish(&sub, good.replacen("move-page", "replay", 1)).await;
    // The id is part of what is signed: a replay under another id is a bad signature, under
    // the same id a replayed serial.
    refused(&sub, "replay", "bad_signature").await;
    sub.clear();
    publish(&sub, good).await;
    refused(&sub, "move-page", "replayed").await;

    let hostile = text(http3)
        .replacen(TOKEN, "attackers-token-0123456789", 1)
        .replacen("unit = 1\n", "unit = 9\n", 1);
    publish(&sub, openssl_signed(&key, "test", "silence", 2, &hostile)).await;
    let back = final_result(&sub, "silence", Duration::from_secs(60)).await;
    assert_eq!(back["status"], "rolled_back", "{back}");
    assert!(
        back["message"]
            .as_str()
            .unwrap()
            .contains("did not answer again: m"),
        "{back}"
    );
    assert_eq!(
        back["config"], hash_kept,
        "the hash of the config that runs again"
    );
    assert_eq!(std::fs::read_to_string(&config).unwrap(), moved);
    assert_eq!(
        get(http2, "/api/v1/status", TOKEN),
        200,
        "the listener of before, with its token"
    );
    assert_eq!(
        get(http3, "/healthz", TOKEN),
        0,
        "the pushed listener is closed"
    );
    sub.wait_for("pulsegate/test/gateway", Duration::from_secs(10), |m| {
        m.json()["config"] == hash_kept
    })
    .await
    .expect("the boot marker says the hash of the config that runs");
    drop(gw);
}

/// SIGKILL inside the grace of a push that silences a device: the watch was kept in the state
/// directory before the push was applied, so the next start resumes it, rolls the push back
/// (the old file is back) and answers that push's id `rolled_back`.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_kill_inside_the_grace_still_rolls_the_push_back() {
    let broker = Broker::start();
    let plant = plant(TWO).await;
    let dir = temp_dir("push-kill");
    let http = free_port();
    let first = config_text(&plant, broker.port, &dir, &[M], (http, "", ""));
    let config = write_config(&dir, &first);
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;
    let silent = first.replacen("unit = 1\n", "unit = 9\n", 1);
    publish(&sub, unsigned("doomed", &silent)).await;
    sub.wait_for(
        "pulsegate/test/config/result",
        Duration::from_secs(10),
        |m| m.json()["id"] == "doomed" && m.json()["status"] == "applied",
    )
    .await
    .expect("applied");
    gw.kill();
    assert_eq!(
        std::fs::read_to_string(&config).unwrap(),
        silent,
        "the push was in force"
    );
    let gw = Gateway::start(&config);
    let back = final_result(&sub, "doomed", Duration::from_secs(30)).await;
    assert_eq!(back["status"], "rolled_back", "{back}");
    assert_eq!(
        std::fs::read_to_string(&config).unwrap(),
        first,
        "the old file is back"
    );
    assert!(
        gw.log_text().contains("in force after a start"),
        "{}",
        gw.log_text()
    );
    assert!(!dir.join("remote-watch.json").exists(), "the watch is done");
}

/// Six pushes that each need a restart, at once: six answers (one applied then kept, five
/// busy), none lost to the restart. A push published retained is refused and not applied. A
/// 100 KB push is answered `too_large` with its id. The config file keeps its mode 0600, and
/// `.previous` gets the same.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_push_is_answered_once_and_the_file_keeps_its_mode() {
    use std::os::unix::fs::PermissionsExt as _;
    let broker = Broker::start();
    let plant = plant(TWO).await;
    let dir = temp_dir("push-burst");
    let http = free_port();
    let first = config_text(&plant, broker.port, &dir, &[M], (http, "", ""));
    let config = write_config(&dir, &first);
    std::fs::set_permissions(&config, std::fs::Permissions::from_mode(0o600)).unwrap();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let _gw = Gateway::start(&config);
    sub.expect_any("pulsegate/test/m/a0", Duration::from_secs(10))
        .await;

    let retained = first.replacen(
        "[buses.line1.devices.m]",
        "[buses.line1.devices.n]\nunit = 2\nmodel = \"yl67\"\n\n[buses.line1.devices.m]",
        1,
    );
    assert_ne!(retained, first);
    let status = Command::new("mosquitto_pub")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &broker.port.to_string(),
            "-q",
            "1",
            "-r",
        ])
        .args([
            "-t",
            "pulsegate/test/config/set",
            "-m",
            &unsigned("kept-on-broker", &retained),
        ])
        .status()
        .unwrap();
    assert!(status.success());
    refused(&sub, "kept-on-broker", "retained").await;
    assert_eq!(std::fs::read_to_string(&config).unwrap(), first);
    let _ = Command::new("mosquitto_pub")
        .args([
            "-h",
            "127.0.0.1",
            "-p",
            &broker.port.to_string(),
            "-r",
            "-n",
        ])
        .args(["-t", "pulsegate/test/config/set"])
        .status();

    let big =
        json!({"id": "big", "toml": format!("{first}#{}\n", "x".repeat(100 * 1024))}).to_string();
    publish(&sub, big).await;
    refused(&sub, "big", "too_large").await;

    let ids: Vec<String> = (1..=6).map(|i| format!("burst-{i}")).collect();
    for (i, id) in ids.iter().enumerate() {
        let flush = first.replacen(
            "state_flush = \"500ms\"",
            &format!("state_flush = \"{}s\"", i + 1),
            1,
        );
        publish(&sub, unsigned(id, &flush)).await;
    }
    let mut kept = 0;
    for id in &ids {
        let r = final_result(&sub, id, Duration::from_secs(40)).await;
        match (r["status"].as_str(), r["error"].as_str()) {
            (Some("kept"), _) => kept += 1,
            (Some("refused"), Some("busy")) => {}
            other => panic!("{id}: {other:?} {r}"),
        }
    }
    assert_eq!(kept, 1, "one applied and kept, the others busy");
    tokio::time::sleep(Duration::from_secs(2)).await;
    for id in &ids {
        assert_eq!(finals(&sub, id).len(), 1, "{id} answered once");
    }
    for file in [config.clone(), dir.join("pulsegate.toml.previous")] {
        let mode = std::fs::metadata(&file).unwrap().permissions().mode() & 0o777;
        assert_eq!(mode, 0o600, "{}", file.display());
    }
}

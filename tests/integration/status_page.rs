//! The status page in a real headless Chromium (Debian's, driven over the DevTools protocol),
//! against the simulated plant and a real Mosquitto: what a technician sees, that it is live,
//! that a name or unit from the config is shown as text and runs nothing, and that the page
//! asks no other host. Then the API against what MQTT published, and the token's rules.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use serde_json::{Value, json};

use crate::support::*;

/// A unit that would run a script if the page put it in as markup.
const HOSTILE_UNIT: &str = "<img src=x onerror=alert(1)>";

// --- a headless Chromium, driven over the DevTools protocol ---------------------------------

/// Chromium with a fresh profile, killed on drop, and its page's DevTools connection.
struct Browser {
    child: Child,
    profile: PathBuf,
    ws: tungstenite::WebSocket<TcpStream>,
    next_id: u64,
    /// Every event the page reported (method and params), in order.
    events: Vec<Value>,
}

fn chromium() -> &'static str {
    ["/usr/bin/chromium", "/usr/bin/chromium-browser"]
        .into_iter()
        .find(|p| Path::new(p).exists())
        .expect("chromium is not installed: run the README's test command (scripts/test), which installs it")
}

impl Browser {
    fn start(name: &str) -> Browser {
        let profile = temp_dir(&format!("chromium-{name}"));
        let child = Command::new(chromium())
            .args([
                "--headless",
                "--no-sandbox",
                "--disable-gpu",
                "--disable-background-networking",
                "--disable-component-update",
                "--disable-sync",
                "--no-first-run",
                "--window-size=1280,800",
                "--remote-debugging-port=0",
            ])
            .arg(format!("--user-data-dir={}", profile.display()))
            .arg("about:blank")
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromium");
        let port = devtools_port(&profile);
        let ws_url = page_target(port);
        let stream = TcpStream::connect(("127.0.0.1", port)).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(10)))
            .unwrap();
        let (ws, _) = tungstenite::client(ws_url.as_str(), stream).expect("DevTools websocket");
        let mut b = Browser {
            child,
            profile,
            ws,
            next_id: 0,
            events: Vec::new(),
        };
        for domain in ["Page.enable", "Network.enable", "Runtime.enable"] {
            b.call(domain, json!({}));
        }
        b
    }

    /// A DevTools command; events that arrive before its answer are kept.
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let msg = json!({"id": id, "method": method, "params": params}).to_string();
        self.ws.send(tungstenite::Message::text(msg)).unwrap();
        loop {
            let m = self.ws.read().expect("DevTools answer within 10 s");
            let Ok(text) = m.to_text() else { continue };
            let v: Value = serde_json::from_str(text).unwrap_or(Value::Null);
            if v["id"] == id {
                assert!(v.get("error").is_none(), "{method}: {v}");
                return v["result"].clone();
            }
            if v.get("method").is_some() {
                self.events.push(v);
            }
        }
    }

    fn open(&mut self, url: &str) {
        self.call("Page.navigate", json!({ "url": url }));
    }

    /// The value of a JavaScript expression in the page.
    fn eval(&mut self, expression: &str) -> Value {
        let r = self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true}),
        );
        r["result"]["value"].clone()
    }

    /// Evaluates `expression` until `pred` holds on it, or `within` passes; returns the last.
    fn wait_for(
        &mut self,
        expression: &str,
        within: Duration,
        pred: impl Fn(&Value) -> bool,
    ) -> (Value, bool) {
        let deadline = Instant::now() + within;
        loop {
            let v = self.eval(expression);
            if pred(&v) {
                return (v, true);
            }
            if Instant::now() >= deadline {
                return (v, false);
            }
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    fn events_named(&self, method: &str) -> Vec<&Value> {
        self.events
            .iter()
            .filter(|e| e["method"] == method)
            .collect()
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
        let _ = std::fs::remove_dir_all(&self.profile);
    }
}

/// The DevTools port Chromium chose (`--remote-debugging-port=0` writes it to its profile).
fn devtools_port(profile: &Path) -> u16 {
    let file = profile.join("DevToolsActivePort");
    let deadline = Instant::now() + Duration::from_secs(20);
    loop {
        if let Some(port) = std::fs::read_to_string(&file)
            .ok()
            .and_then(|t| t.lines().next()?.trim().parse().ok())
        {
            return port;
        }
        assert!(
            Instant::now() < deadline,
            "chromium wrote no DevToolsActivePort"
        );
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The websocket of Chromium's page target.
fn page_target(port: u16) -> String {
    let deadline = Instant::now() + Duration::from_secs(10);
    loop {
        let (_, _, body) = http(port, "GET", "/json/list", &[], "");
        let list: Value = serde_json::from_str(&body).unwrap_or(Value::Null);
        if let Some(url) = list
            .as_array()
            .and_then(|l| l.iter().find(|t| t["type"] == "page"))
            .and_then(|t| t["webSocketDebuggerUrl"].as_str())
        {
            return url.to_string();
        }
        assert!(Instant::now() < deadline, "no page target: {body}");
        std::thread::sleep(Duration::from_millis(50));
    }
}

// --- plain HTTP ----------------------------------------------------------------------------

/// One HTTP/1.1 request on loopback: (status, head, body).
pub(crate) fn http(
    port: u16,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &str,
) -> (u16, String, String) {
    let Ok(mut s) = TcpStream::connect(("127.0.0.1", port)) else {
        return (0, String::new(), String::new());
    };
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut req =
        format!("{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nConnection: close\r\n");
    for (k, v) in headers {
        req += &format!("{k}: {v}\r\n");
    }
    if !body.is_empty() {
        req += &format!("Content-Length: {}\r\n", body.len());
    }
    req += "\r\n";
    req += body;
    s.write_all(req.as_bytes()).unwrap();
    let mut text = String::new();
    let _ = s.read_to_string(&mut text);
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .unwrap_or(0);
    let (head, body) = text.split_once("\r\n\r\n").unwrap_or((&text, ""));
    (status, head.to_string(), body.to_string())
}

/// An open `GET /api/v1/events`: the connection, and the head with what came after it.
fn open_stream(port: u16, headers: &[(&str, &str)]) -> (TcpStream, String) {
    let mut s = TcpStream::connect(("127.0.0.1", port)).unwrap();
    s.set_read_timeout(Some(Duration::from_secs(5))).unwrap();
    let mut req = format!("GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n");
    for (k, v) in headers {
        req += &format!("{k}: {v}\r\n");
    }
    s.write_all((req + "\r\n").as_bytes()).unwrap();
    let mut got = Vec::new();
    let mut buf = [0u8; 65536];
    while !String::from_utf8_lossy(&got).contains("\r\n\r\n") {
        match s.read(&mut buf) {
            Ok(0) | Err(_) => break,
            Ok(n) => got.extend_from_slice(&buf[..n]),
        }
    }
    (s, String::from_utf8_lossy(&got).into_owned())
}

/// The next snapshot a stream sends (its `data:` line as JSON), or `None` when it ended.
fn next_event(s: &mut TcpStream, pending: &mut Vec<u8>) -> Option<Value> {
    let mut buf = [0u8; 65536];
    loop {
        let text = String::from_utf8_lossy(pending).into_owned();
        if let Some(at) = text.find("data: ") {
            if let Some(end) = text[at..].find("\n\n") {
                let json = &text[at + 6..at + end];
                pending.drain(..(at + end + 2).min(pending.len()));
                return serde_json::from_str(json).ok();
            }
        }
        match s.read(&mut buf) {
            Ok(0) | Err(_) => return None,
            Ok(n) => pending.extend_from_slice(&buf[..n]),
        }
    }
}

fn api(port: u16, headers: &[(&str, &str)]) -> Value {
    let (status, _, body) = http(port, "GET", "/api/v1/status", headers, "");
    assert_eq!(status, 200, "{body}");
    serde_json::from_str(&body).unwrap()
}

// --- the plant ------------------------------------------------------------------------------

const PLANT: &str = r#"
[buses.line1.devices.a]
unit = 1
model = "yl67"
modes = [1, 1, 1, 1]
channels.a0 = { rate = 100.0 }
[buses.line1.devices.b]
unit = 2
model = "wj157"
channels.enc0 = { rate = -50.0 }
"#;

const DEVICES: [(&str, &str, u8, &str, &str); 2] = [
    ("line1", "a", 1, "yl67", "200ms"),
    ("line1", "b", 2, "wj157", "200ms"),
];

/// `[metrics]` on `port`, `metrics` extra keys, and the hostile unit on channel a0 of a.
fn page_toml(port: u16, metrics: &str) -> String {
    format!(
        "[metrics]\nlisten = \"127.0.0.1:{port}\"\n{metrics}\n[buses.line1.devices.a.channels.a0]\nscale = 0.01\nunit = {HOSTILE_UNIT:?}\n"
    )
}

/// Waits until the endpoint answers.
pub(crate) fn wait_listening(port: u16) {
    let deadline = Instant::now() + Duration::from_secs(10);
    while http(port, "GET", "/healthz", &[], "").0 == 0 {
        assert!(Instant::now() < deadline, "the HTTP endpoint did not start");
        std::thread::sleep(Duration::from_millis(50));
    }
}

/// The text of the first element matching `selector`, as a JavaScript expression.
fn text_of(selector: &str) -> String {
    format!("(document.querySelector({selector:?}) || {{}}).textContent || null")
}

/// A count as the page writes it (thin spaces between thousands) as a number.
fn count_in(v: &Value) -> Option<i64> {
    let digits: String = v
        .as_str()?
        .chars()
        .filter(|c| c.is_ascii_digit() || *c == '-')
        .collect();
    digits.parse().ok()
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_page_in_a_real_browser_shows_the_plant_live_and_runs_nothing_from_the_config() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("status-page");
    let port = free_port();
    let gw = start_gateway(&plant, broker.port, &dir, &DEVICES, &page_toml(port, ""));
    wait_listening(port);
    let mut browser = tokio::task::block_in_place(|| Browser::start("page"));
    let page = format!("http://127.0.0.1:{port}/");
    tokio::task::block_in_place(|| browser.open(&page));

    // Device and channel names appear, as the names they are.
    let (names, ok) = tokio::task::block_in_place(|| {
        browser.wait_for(
            "[...document.querySelectorAll('[data-channel]')].map(e => e.dataset.channel)",
            Duration::from_secs(10),
            |v| {
                v.as_array()
                    .is_some_and(|l| l.contains(&json!("a/a0")) && l.contains(&json!("b/enc0")))
            },
        )
    });
    assert!(ok, "channels on the page: {names}");
    let devices = tokio::task::block_in_place(|| {
        browser.eval("[...document.querySelectorAll('[data-device] h3')].map(e => e.textContent)")
    });
    assert_eq!(devices, json!(["a", "b"]));

    // A channel's count rises within 3 s.
    let count = text_of("[data-channel=\"a/a0\"] .count");
    let first = count_in(&tokio::task::block_in_place(|| browser.eval(&count))).expect("a count");
    let (later, rose) = tokio::task::block_in_place(|| {
        browser.wait_for(&count, Duration::from_secs(3), |v| {
            count_in(v).is_some_and(|c| c > first)
        })
    });
    assert!(rose, "the count stayed at {first} for 3 s (last {later})");

    // The hostile unit is text on the page and ran nothing.
    let unit =
        tokio::task::block_in_place(|| browser.eval(&text_of("[data-channel=\"a/a0\"] .unit")));
    assert_eq!(unit.as_str().map(str::trim), Some(HOSTILE_UNIT));
    let images =
        tokio::task::block_in_place(|| browser.eval("document.querySelectorAll('img').length"));
    assert_eq!(images, json!(0), "the unit became an element");

    // A device the simulator silences shows offline within its timeout: 3 failed polls (200 ms
    // apart, 100 ms timeout each) make it offline, the page asks once a second.
    plant
        .with_module("line1", 2, |m, _| m.silent = true)
        .unwrap();
    let silenced = Instant::now();
    let status = text_of("[data-device=\"b\"] .status");
    let (shown, offline) = tokio::task::block_in_place(|| {
        browser.wait_for(&status, Duration::from_secs(4), |v| v == "offline")
    });
    assert!(
        offline,
        "b shows {shown} {:?} after it was silenced",
        silenced.elapsed()
    );
    let other =
        tokio::task::block_in_place(|| browser.eval(&text_of("[data-device=\"a\"] .status")));
    assert_eq!(other, json!("online"));

    // No script from the config ran (no dialog opened), and every request went to the gateway.
    let b = &browser;
    assert!(
        b.events_named("Page.javascriptDialogOpening").is_empty(),
        "a dialog opened"
    );
    let urls: Vec<&str> = b
        .events_named("Network.requestWillBeSent")
        .iter()
        .filter_map(|e| e["params"]["request"]["url"].as_str())
        .collect();
    assert!(
        urls.iter().any(|u| u.ends_with("/api/v1/events")),
        "the page listens to the event stream: {urls:?}"
    );
    let elsewhere: Vec<&&str> = urls.iter().filter(|u| !u.starts_with(&page)).collect();
    assert!(
        elsewhere.is_empty(),
        "requests to other hosts: {elsewhere:?}"
    );
    let errors = b.events_named("Runtime.exceptionThrown");
    assert!(errors.is_empty(), "the page's script failed: {errors:?}");
    drop(browser);
    drop(gw);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn the_api_says_what_mqtt_published_for_the_same_poll() {
    let broker = Broker::start();
    let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
    let plant = plant(PLANT).await;
    let dir = temp_dir("status-api");
    let port = free_port();
    let gw = start_gateway(&plant, broker.port, &dir, &DEVICES, &page_toml(port, ""));
    sub.expect_any("pulsegate/test/b/enc0", Duration::from_secs(10))
        .await;
    let status = tokio::task::spawn_blocking(move || api(port, &[]))
        .await
        .unwrap();
    assert_eq!(status["api"], 1);
    assert_eq!(status["gateway"]["id"], "test");
    assert_eq!(
        status["gateway"]["config_hash"].as_str().map(str::len),
        Some(64)
    );
    let mut compared = 0;
    for d in status["devices"].as_array().unwrap() {
        let device = d["name"].as_str().unwrap();
        let published = sub
            .wait_for(
                &format!("pulsegate/test/{device}/status"),
                Duration::from_secs(3),
                |_| true,
            )
            .await
            .expect("a device status on MQTT");
        assert_eq!(
            d["status"].as_str(),
            Some(published.payload.as_str()),
            "{device}"
        );
        for c in d["channels"].as_array().unwrap() {
            let topic = format!("pulsegate/test/{device}/{}", c["name"].as_str().unwrap());
            let seq = c["seq"].clone();
            let m = sub
                .wait_for(&topic, Duration::from_secs(3), |m| m.json()["seq"] == seq)
                .await
                .unwrap_or_else(|| panic!("no reading with seq {seq} on {topic}"));
            let r = m.json();
            assert_eq!(
                (&c["count"], &c["total"], &c["delta"]),
                (&r["count"], &r["total"], &r["delta"]),
                "{topic}"
            );
            compared += 1;
        }
    }
    assert!(compared >= 2, "compared {compared} channels");
    drop(gw);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_token_guards_the_page_and_the_api_and_never_metrics_or_healthz() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("status-token");
    let port = free_port();
    let token = "s3cret-t0ken-for-the-cabinet";
    let extra = page_toml(port, &format!("token = {token:?}"));
    let gw = start_gateway(&plant, broker.port, &dir, &DEVICES, &extra);
    tokio::task::spawn_blocking(move || {
        wait_listening(port);
        let bearer = format!("Bearer {token}");
        let (_, head) = open_stream(port, &[]);
        assert!(
            head.starts_with("HTTP/1.1 401"),
            "the stream without the token: {head}"
        );
        let (_, head) = open_stream(port, &[("Authorization", &bearer)]);
        assert!(
            head.starts_with("HTTP/1.1 200"),
            "the stream with the token: {head}"
        );
        for path in ["/", "/status.css", "/status.js", "/api/v1/status"] {
            let (status, head, _) = http(port, "GET", path, &[], "");
            assert_eq!(status, 401, "{path} without the token: {head}");
            let (status, ..) = http(
                port,
                "GET",
                path,
                &[("Authorization", "Bearer wrong-token-0123456789")],
                "",
            );
            assert_eq!(status, 401, "{path} with a wrong token");
            let (status, ..) = http(port, "GET", path, &[("Authorization", &bearer)], "");
            assert_eq!(status, 200, "{path} with the token");
        }
        for path in ["/metrics", "/healthz"] {
            let (status, ..) = http(port, "GET", path, &[], "");
            assert!(
                status == 200 || status == 503,
                "{path} asks for no token: {status}"
            );
        }
        // The login form sets the cookie a browser then sends.
        let (status, _, body) = http(port, "GET", "/", &[], "");
        assert!(status == 401 && body.contains("<form"), "{body}");
        let form = [("Content-Type", "application/x-www-form-urlencoded")];
        let (status, ..) = http(port, "POST", "/login", &form, "token=not-it-at-all-0123");
        assert_eq!(status, 401);
        let (status, head, _) = http(port, "POST", "/login", &form, &format!("token={token}"));
        assert_eq!(status, 303, "{head}");
        let cookie = head
            .lines()
            .find_map(|l| l.strip_prefix("set-cookie: "))
            .expect("a cookie")
            .to_string();
        assert!(
            cookie.contains("HttpOnly") && cookie.contains("SameSite=Strict"),
            "{cookie}"
        );
        let pair = cookie.split(';').next().unwrap();
        let (status, ..) = http(port, "GET", "/api/v1/status", &[("Cookie", pair)], "");
        assert_eq!(status, 200, "with the login's cookie");

        // The page's files, all of them: under 150 KB, and each under the content policy.
        let mut total = 0;
        for path in ["/", "/status.css", "/status.js", "/login", "/login.css"] {
            let (status, head, body) = http(port, "GET", path, &[("Authorization", &bearer)], "");
            assert_eq!(status, 200, "{path}");
            assert!(
                head.contains("content-security-policy: default-src 'self'"),
                "{path}: {head}"
            );
            total += body.len();
        }
        assert!(total < 150 * 1024, "the page is {total} bytes");

        // Slow and idle clients cost the page nothing either.
        let idle: Vec<_> = (0..20)
            .map(|_| TcpStream::connect(("127.0.0.1", port)).unwrap())
            .collect();
        drop(idle);
        let (status, ..) = http(
            port,
            "GET",
            "/api/v1/status",
            &[("Authorization", &bearer)],
            "",
        );
        assert_eq!(status, 200);
    })
    .await
    .unwrap();
    drop(gw);
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn open_pages_get_the_snapshot_every_second_and_never_keep_a_probe_out() {
    let broker = Broker::start();
    let plant = plant(PLANT).await;
    let dir = temp_dir("status-stream");
    let port = free_port();
    let gw = start_gateway(&plant, broker.port, &dir, &DEVICES, &page_toml(port, ""));
    tokio::task::spawn_blocking(move || {
        wait_listening(port);
        // A stream: the snapshot at once, then a newer one about every second.
        let (mut s, head) = open_stream(port, &[]);
        let lower = head.to_ascii_lowercase();
        assert!(
            lower.starts_with("http/1.1 200") && lower.contains("content-type: text/event-stream"),
            "{head}"
        );
        assert!(
            lower.contains("content-security-policy: default-src 'self'"),
            "{head}"
        );
        let mut pending = head
            .split_once("\r\n\r\n")
            .map(|(_, rest)| rest.as_bytes().to_vec())
            .unwrap_or_default();
        let first = next_event(&mut s, &mut pending).expect("the snapshot at hand");
        assert_eq!(first["api"], 1);
        let mut later = first.clone();
        let started = Instant::now();
        while later["now_ms"] == first["now_ms"] {
            later = next_event(&mut s, &mut pending).expect("a newer snapshot");
        }
        assert!(
            started.elapsed() < Duration::from_millis(2500),
            "the next snapshot came after {:?}",
            started.elapsed()
        );
        let api = api(port, &[]);
        assert_eq!(api["gateway"]["id"], later["gateway"]["id"]);

        // 70 open pages (64 streams at most): /healthz still answers at once, the six oldest
        // streams are closed (their browsers connect again), the newest are served.
        let mut pages: Vec<(TcpStream, String)> = (0..70).map(|_| open_stream(port, &[])).collect();
        assert!(pages.iter().all(|(_, h)| h.starts_with("HTTP/1.1 200")));
        let (status, _, body) = http(port, "GET", "/healthz", &[], "");
        assert_eq!(status, 200, "/healthz with 70 pages open: {body}");
        fn three_events((s, h): &mut (TcpStream, String)) -> bool {
            let mut rest = h
                .split_once("\r\n\r\n")
                .map(|(_, r)| r.as_bytes().to_vec())
                .unwrap_or_default();
            let mut n = 0;
            while next_event(s, &mut rest).is_some() {
                n += 1;
                if n == 3 {
                    return true;
                }
            }
            false
        }
        let (oldest, newest) = pages.split_at_mut(7);
        let closed = oldest
            .iter_mut()
            .map(three_events)
            .filter(|seen| !seen)
            .count();
        assert!(closed >= 6, "{closed} of the 7 oldest streams were closed");
        assert!(
            newest.iter_mut().take(5).all(three_events),
            "the newest streams keep getting snapshots"
        );
        drop(s);
    })
    .await
    .unwrap();
    drop(gw);
}

#[test]
fn a_listener_off_loopback_without_a_token_is_a_config_error() {
    let dir = temp_dir("status-open");
    let text = format!(
        "[gateway]\nstate_dir = {:?}\n[mqtt]\nhost = \"127.0.0.1\"\n[metrics]\nlisten = \"0.0.0.0:{}\"\n[buses.l]\nport = \"/dev/null\"\n[buses.l.devices.m]\nunit = 1\nmodel = \"yl67\"\n",
        dir,
        free_port()
    );
    let config = write_config(&dir, &text);
    for command in ["check", "run"] {
        let out = Command::new(bin())
            .args([command, "--config"])
            .arg(&config)
            .output()
            .unwrap();
        let stderr = String::from_utf8_lossy(&out.stderr);
        assert!(!out.status.success(), "{command} accepted it: {stderr}");
        assert!(stderr.contains("metrics.token"), "{command}: {stderr}");
    }
}

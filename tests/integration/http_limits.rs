//! What a hostile client on the HTTP endpoint's network can cost it, against the real gateway
//! on loopback: a script guessing the token is locked out, counted and heard of a few times
//! (not once per guess), and a flood of connections, short, idle or half-written, never keeps
//! a probe of `/healthz` or a scrape of `/metrics` from its answer.

use std::collections::VecDeque;
use std::io::{Read, Write};
use std::net::TcpStream;
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicUsize, Ordering};
use std::time::{Duration, Instant};

use crate::status_page::{http, wait_listening};
use crate::support::*;
use pulsegate::sim::Plant;

const TOKEN: &str = "s3cret-t0ken-for-the-cabinet";

/// The gateway of one meter with `[metrics]` on `port` and `extra` keys in it, and what it
/// talks to.
async fn gateway_on(name: &str, port: u16, extra: &str) -> (Broker, Plant, Gateway) {
    let broker = Broker::start();
    let plant = plant(ONE_METER).await;
    let dir = temp_dir(name);
    let metrics = format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n{extra}\n");
    let text = one_meter_toml(&plant, broker.port, &dir, &metrics);
    let gw = Gateway::start(&write_config(&dir, &text));
    (broker, plant, gw)
}

/// The value of the series `name` (with its labels) in a scrape.
fn series(scrape: &str, name: &str) -> u64 {
    scrape
        .lines()
        .find(|l| l.starts_with(name) && l[name.len()..].starts_with(' '))
        .and_then(|l| l.rsplit(' ').next()?.parse().ok())
        .unwrap_or_else(|| panic!("no {name} in the scrape"))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn three_thousand_wrong_logins_are_answered_429_counted_and_logged_a_handful_of_times() {
    let port = free_port();
    let (_broker, _plant, gw) =
        gateway_on("http-logins", port, &format!("token = {TOKEN:?}")).await;
    let statuses = tokio::task::spawn_blocking(move || {
        wait_listening(port);
        let threads: Vec<_> = (0..4)
            .map(|t| {
                std::thread::spawn(move || {
                    let form = [("Content-Type", "application/x-www-form-urlencoded")];
                    (0..750)
                        .map(|i| {
                            let guess = format!("token=guess-{t}-{i}-0123456789");
                            http(port, "POST", "/login", &form, &guess).0
                        })
                        .collect::<Vec<u16>>()
                })
            })
            .collect();
        threads
            .into_iter()
            .flat_map(|t| t.join().unwrap())
            .collect::<Vec<u16>>()
    })
    .await
    .unwrap();
    assert_eq!(statuses.len(), 3000);
    let limited = statuses.iter().filter(|s| **s == 429).count();
    let wrong = statuses.iter().filter(|s| **s == 401).count();
    assert_eq!(limited + wrong, 3000, "every guess answered 401 or 429");
    assert!(
        limited >= 2990,
        "only {limited} of 3000 guesses were answered 429"
    );

    let checks = tokio::task::spawn_blocking(move || {
        // During the lockout even the right token is refused, and the answer says when to
        // come back.
        let form = [("Content-Type", "application/x-www-form-urlencoded")];
        let right = http(port, "POST", "/login", &form, &format!("token={TOKEN}"));
        let bearer = format!("Bearer {TOKEN}");
        let api = http(
            port,
            "GET",
            "/api/v1/status",
            &[("Authorization", &bearer)],
            "",
        );
        let scrape = crate::metrics::http_get(port, "/metrics").1;
        (right, api.0, scrape)
    })
    .await
    .unwrap();
    let ((status, head, body), api, scrape) = checks;
    assert_eq!(status, 429, "the right token during the lockout: {head}");
    let retry = head
        .lines()
        .find_map(|l| l.strip_prefix("retry-after: "))
        .and_then(|s| s.trim().parse::<u64>().ok());
    assert!(retry.is_some_and(|s| (1..=60).contains(&s)), "{head}");
    assert!(
        body.contains("<form"),
        "a browser is shown the form: {body}"
    );
    assert_eq!(api, 429, "a bearer is a token given like any other");

    let counted = |result: &str| {
        series(
            &scrape,
            &format!("pulsegate_http_login_failures_total{{result=\"{result}\"}}"),
        )
    };
    assert_eq!(
        counted("wrong_token"),
        wrong as u64 + 1,
        "the locking guess is wrong too"
    );
    assert_eq!(counted("limited"), limited as u64 - 1 + 2);

    let log = gw.log_text();
    let lines: Vec<&str> = log
        .lines()
        .filter(|l| l.contains("status page:") && l.contains("token"))
        .collect();
    assert!(
        (1..=12).contains(&lines.len()),
        "{} log lines about the guesses:\n{}",
        lines.len(),
        lines.join("\n")
    );
    assert!(
        lines.iter().any(|l| l.contains("wrong tokens within 60 s")),
        "the lockout is said: {lines:#?}"
    );
}

/// What a client of the flood does with each connection it opens.
#[derive(Clone, Copy)]
enum Churn {
    /// Closes it at once.
    Brief,
    /// Says nothing; holds its last `n` connections.
    Idle(usize),
    /// Sends half of a `/healthz` request head and waits; holds its last `n` connections.
    HalfWritten(usize),
}

/// Connections the whole flood makes at most (the probes after it are answered all the same).
const FLOOD: usize = 30_000;

/// A thread that churns connections to `port` until `stop`, [`FLOOD`] of them or 60 s.
fn churn(
    port: u16,
    how: Churn,
    stop: Arc<AtomicBool>,
    made: Arc<AtomicUsize>,
) -> std::thread::JoinHandle<()> {
    std::thread::spawn(move || {
        let started = Instant::now();
        let addr = std::net::SocketAddr::from(([127, 0, 0, 1], port));
        let mut held = VecDeque::new();
        while !stop.load(Ordering::Relaxed)
            && made.load(Ordering::Relaxed) < FLOOD
            && started.elapsed() < Duration::from_secs(60)
        {
            // Not the kernel's second-long wait when the endpoint's queue is full: the flood
            // goes on at once with the next connection.
            let Ok(mut s) = TcpStream::connect_timeout(&addr, Duration::from_millis(20)) else {
                continue;
            };
            made.fetch_add(1, Ordering::Relaxed);
            reset_on_close(&s);
            let hold = match how {
                Churn::Brief => 0,
                Churn::Idle(n) => n,
                Churn::HalfWritten(n) => {
                    let _ = s.write_all(b"GET /healthz HTTP/1.1\r\nHost: 127.0.0.1\r\n");
                    n
                }
            };
            held.push_back(s);
            while held.len() > hold {
                held.pop_front();
            }
        }
    })
}

/// Makes closing `s` a reset: the flood leaves no TIME_WAIT behind on this side, whose tens of
/// thousands would make every `connect` of the test search long for a free port.
fn reset_on_close(s: &TcpStream) {
    use std::os::fd::AsRawFd;
    let linger = libc::linger {
        l_onoff: 1,
        l_linger: 0,
    };
    // SAFETY: a valid socket and a `linger` of the size given.
    let r = unsafe {
        libc::setsockopt(
            s.as_raw_fd(),
            libc::SOL_SOCKET,
            libc::SO_LINGER,
            (&linger as *const libc::linger).cast(),
            std::mem::size_of::<libc::linger>() as libc::socklen_t,
        )
    };
    assert_eq!(r, 0, "SO_LINGER");
}

/// What a probe got: its status and body, or how it was lost.
type Probed = Result<(u16, String), String>;

/// One probe of `path`.
fn probe(port: u16, path: &str) -> Probed {
    let mut s = TcpStream::connect(("127.0.0.1", port)).map_err(|e| format!("connect: {e}"))?;
    // A guard against a hang, not a timing target.
    s.set_read_timeout(Some(Duration::from_secs(10))).unwrap();
    let req = format!("GET {path} HTTP/1.1\r\nHost: 127.0.0.1\r\nConnection: close\r\n\r\n");
    s.write_all(req.as_bytes())
        .map_err(|e| format!("write: {e}"))?;
    let mut got = Vec::new();
    s.read_to_end(&mut got).map_err(|e| format!("read: {e}"))?;
    let text = String::from_utf8_lossy(&got);
    let status = text
        .split_whitespace()
        .nth(1)
        .and_then(|c| c.parse().ok())
        .ok_or_else(|| format!("no answer ({} bytes)", got.len()))?;
    let body = text.split_once("\r\n\r\n").map(|(_, b)| b).unwrap_or("");
    Ok((status, body.to_string()))
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_probe_and_scrape_is_answered_while_others_churn_and_hold_connections() {
    let port = free_port();
    let (_broker, _plant, _gw) = gateway_on("http-churn", port, "").await;
    let outcomes = tokio::task::spawn_blocking(move || {
        wait_listening(port);
        let stop = Arc::new(AtomicBool::new(false));
        let made = Arc::new(AtomicUsize::new(0));
        let flood = [Churn::Brief, Churn::Idle(300), Churn::HalfWritten(100)];
        let churners: Vec<_> = flood
            .into_iter()
            .map(|how| churn(port, how, stop.clone(), made.clone()))
            .collect();
        // Probe once the flood is under way (a guard against a hang, not a timing target).
        let deadline = Instant::now() + Duration::from_secs(20);
        while made.load(Ordering::Relaxed) < 2000 && Instant::now() < deadline {
            std::thread::sleep(Duration::from_millis(10));
        }
        let during = made.load(Ordering::Relaxed);
        let outcomes: Vec<(&str, Probed)> = (0..100)
            .map(|i| {
                let path = if i % 5 == 4 { "/metrics" } else { "/healthz" };
                (path, probe(port, path))
            })
            .collect();
        let flooded = made.load(Ordering::Relaxed) - during;
        stop.store(true, Ordering::Relaxed);
        for c in churners {
            c.join().unwrap();
        }
        (outcomes, flooded)
    })
    .await
    .unwrap();
    let (outcomes, flooded) = outcomes;
    assert!(
        flooded >= 1000,
        "the flood made only {flooded} connections while the probes ran"
    );
    let lost: Vec<String> = outcomes
        .iter()
        .filter_map(|(path, o)| match o {
            Ok((200 | 503, body)) if *path == "/healthz" && !body.is_empty() => None,
            Ok((200, body)) if *path == "/metrics" && body.contains("pulsegate_build_info") => None,
            Ok((status, body)) => Some(format!("{path}: {status} {body:?}")),
            Err(e) => Some(format!("{path}: {e}")),
        })
        .collect();
    assert!(
        lost.is_empty(),
        "{} of 100 probes lost among {flooded} connections of others:\n{}",
        lost.len(),
        lost.join("\n")
    );
}

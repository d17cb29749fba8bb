//! The status page's cost: the gateway's CPU per Modbus transaction while 50 pages are open
//! (each listening to `/api/v1/events`, as the page does) and while 50 scripts ask
//! `/api/v1/status` once a second each (a new connection each), against the same gateway with
//! no client, in the same run. One gateway process polls a Modbus TCP plant (16 YL67 every
//! 50 ms) and publishes to Mosquitto; windows with no client, with the pages and with the
//! scripts follow each other (`BENCH_ROUNDS`, default 3, of `BENCH_STATUS_SECS`, default 10 s
//! each), so whatever else the machine does weighs on all. CPU is the gateway's whole process
//! (every thread's `schedstat`), transactions are the FC03 answers the simulated modules gave.
//! The clients run in the bench's own process.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;

use super::{Figure, Mosquitto, free_port, gateway_toml, tcp_plant, temp_dir};

const CLIENTS: usize = 50;

/// Nanoseconds of CPU every thread of `pid` has used.
pub(super) fn cpu_ns(pid: u32) -> u64 {
    let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) else {
        return 0;
    };
    tasks
        .flatten()
        .filter_map(|t| std::fs::read_to_string(t.path().join("schedstat")).ok())
        .filter_map(|s| s.split_whitespace().next()?.parse::<u64>().ok())
        .sum()
}

/// FC03 answers the plant's modules gave.
pub(super) fn reads(plant: &Plant) -> u64 {
    let b = plant.bus("hall0").expect("bus of the plant");
    let modules = b.modules.lock().unwrap_or_else(|e| e.into_inner());
    modules.values().map(|m| m.reads).sum()
}

/// Bytes of the last answer (to print its size).
static LAST_SIZE: AtomicU64 = AtomicU64::new(0);

/// One `GET /api/v1/status`; whether it answered 200.
fn ask(port: u16) -> bool {
    let Ok(mut s) = TcpStream::connect(("127.0.0.1", port)) else {
        return false;
    };
    let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
    let req = "GET /api/v1/status HTTP/1.1
Host: 127.0.0.1
Connection: close

";
    if s.write_all(req.as_bytes()).is_err() {
        return false;
    }
    let mut answer = Vec::new();
    let _ = s.read_to_end(&mut answer);
    LAST_SIZE.store(answer.len() as u64, Ordering::Relaxed);
    answer.starts_with(b"HTTP/1.1 200")
}

/// 50 open pages while `on` is set: each an event stream, read as it comes (a browser reads
/// its stream at once); each snapshot counts as an answer. A page whose window ends closes its
/// stream.
fn pages(port: u16, on: Arc<AtomicBool>, stop: Arc<AtomicBool>, answered: Arc<AtomicU64>) {
    for _ in 0..CLIENTS {
        let (on, stop, answered) = (on.clone(), stop.clone(), answered.clone());
        std::thread::spawn(move || {
            while !stop.load(Ordering::Relaxed) {
                if !on.load(Ordering::Relaxed) {
                    std::thread::sleep(Duration::from_millis(50));
                    continue;
                }
                let Ok(mut s) = TcpStream::connect(("127.0.0.1", port)) else {
                    std::thread::sleep(Duration::from_millis(100));
                    continue;
                };
                let _ = s.set_read_timeout(Some(Duration::from_millis(200)));
                let req = "GET /api/v1/events HTTP/1.1\r\nHost: 127.0.0.1\r\n\r\n";
                if s.write_all(req.as_bytes()).is_err() {
                    continue;
                }
                let mut buf = vec![0u8; 256 * 1024];
                while on.load(Ordering::Relaxed) && !stop.load(Ordering::Relaxed) {
                    match s.read(&mut buf) {
                        Ok(0) => break,
                        Ok(n) => {
                            let events = buf[..n].windows(6).filter(|w| w == b"data: ").count();
                            answered.fetch_add(events as u64, Ordering::Relaxed);
                        }
                        Err(e) if e.kind() == std::io::ErrorKind::WouldBlock => {}
                        Err(e) if e.kind() == std::io::ErrorKind::TimedOut => {}
                        Err(_) => break,
                    }
                }
            }
        });
    }
}

/// 50 scripts, each asking once a second (staggered over the second) while `on` is set.
fn scripts(port: u16, on: Arc<AtomicBool>, stop: Arc<AtomicBool>, answered: Arc<AtomicU64>) {
    for i in 0..CLIENTS {
        let (on, stop, answered) = (on.clone(), stop.clone(), answered.clone());
        std::thread::spawn(move || {
            std::thread::sleep(Duration::from_millis((i * 1000 / CLIENTS) as u64));
            while !stop.load(Ordering::Relaxed) {
                let next = Instant::now() + Duration::from_secs(1);
                if on.load(Ordering::Relaxed) && ask(port) {
                    answered.fetch_add(1, Ordering::Relaxed);
                }
                std::thread::sleep(next.saturating_duration_since(Instant::now()));
            }
        });
    }
}

pub(super) fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

/// A kind of window: its name, the switch of its clients (none for no client), the CPU a
/// transaction of each of its windows, and the answers its clients got in all of them.
type Way = (&'static str, Option<Arc<AtomicBool>>, Vec<f64>, u64);

pub async fn run(figures: &mut Vec<Figure>) {
    let rounds: usize = std::env::var("BENCH_ROUNDS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(3);
    let secs: u64 = std::env::var("BENCH_STATUS_SECS")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(10);
    let mosquitto = Mosquitto::start();
    let sim = tcp_plant(1, 16);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("status");
    let port = free_port();
    let text = gateway_toml(
        &plant,
        &sim,
        9600,
        "50ms",
        &dir,
        &format!("port = {}", mosquitto.1),
    ) + &format!("[metrics]\nlisten = \"127.0.0.1:{port}\"\n");
    let path = dir.join("g.toml");
    std::fs::write(&path, text).unwrap();
    let bin = std::env::var("PULSEGATE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_pulsegate").to_string());
    let mut child = Command::new(bin)
        .args(["run", "--config"])
        .arg(&path)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    let stop = Arc::new(AtomicBool::new(false));
    let answered = Arc::new(AtomicU64::new(0));
    let (page_on, script_on) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    pages(port, page_on.clone(), stop.clone(), answered.clone());
    scripts(port, script_on.clone(), stop.clone(), answered.clone());
    tokio::time::sleep(Duration::from_secs(5)).await;
    let mut ways: [Way; 3] = [
        ("none", None, Vec::new(), 0),
        ("pages", Some(page_on), Vec::new(), 0),
        ("scripts", Some(script_on), Vec::new(), 0),
    ];
    for _ in 0..rounds {
        for (name, switch, cpu, asked) in ways.iter_mut() {
            if let Some(on) = switch {
                on.store(true, Ordering::Relaxed);
            }
            // The clients' first second, and the last one's answers, stay out of the window.
            tokio::time::sleep(Duration::from_secs(1)).await;
            let (c0, t0, a0) = (cpu_ns(pid), reads(&plant), answered.load(Ordering::Relaxed));
            tokio::time::sleep(Duration::from_secs(secs)).await;
            let (c1, t1, a1) = (cpu_ns(pid), reads(&plant), answered.load(Ordering::Relaxed));
            if let Some(on) = switch {
                on.store(false, Ordering::Relaxed);
            }
            let per_tx_us = (c1 - c0) as f64 / 1000.0 / (t1 - t0).max(1) as f64;
            println!(
                "status page: {name}, {:.0} tx/s, {per_tx_us:.1} us CPU a transaction, {:.1} answers/s",
                (t1 - t0) as f64 / secs as f64,
                (a1 - a0) as f64 / secs as f64,
            );
            cpu.push(per_tx_us);
            *asked += a1 - a0;
        }
    }
    println!(
        "status page: a script's answer is {} bytes",
        LAST_SIZE.load(Ordering::Relaxed)
    );
    stop.store(true, Ordering::Relaxed);
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let _ = child.wait();
    drop(mosquitto);
    plant.stop();
    let none = ways[0].2.clone();
    let n = median(none.clone());
    let expected = (CLIENTS as u64 * secs * rounds as u64) as f64;
    for (name, _, with, asked) in &ways[1..] {
        let w = median(with.clone());
        let ratio = w / n;
        let spread: Vec<String> = none
            .iter()
            .zip(with)
            .map(|(n, w)| format!("{:.3}", w / n))
            .collect();
        let (what, target) = match *name {
            "pages" => ("50 open pages (event streams)", "< 1.10"),
            _ => ("50 scripts asking the API once a second", "(context)"),
        };
        figures.push(Figure {
            what: format!("CPU a transaction, {what} / none ({})", spread.join(" ")),
            value: format!(
                "{w:.1} / {n:.1} us, {:.0}% of the snapshots",
                100.0 * *asked as f64 / expected
            ),
            target: target.into(),
            ratio,
            pass: *name != "pages" || (ratio < 1.10 && *asked as f64 >= 0.95 * expected),
        });
    }
}

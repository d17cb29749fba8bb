//! The Modbus server output's cost: 10 PLC-like clients, each reading its own device's first
//! channel block (function 04, 20 registers) as fast as it is answered, against the same
//! gateway with no client, in the same run. One gateway process polls a Modbus TCP plant (16
//! YL67 every 50 ms, ~640 transactions/s) and publishes JSON to Mosquitto; windows with no
//! client and with the 10 follow each other (`BENCH_ROUNDS`, default 3, of
//! `BENCH_PLC_SECS`, default 10 s each), so whatever else the machine does weighs on both.
//! `BENCH_PLC_POLL` sets the modules' poll interval (`1ms`: as fast as they answer, the bus
//! then competing with the clients for the CPU).
//! CPU is the gateway's whole process (every thread's `schedstat`); the bus's poll rate is the
//! FC03 answers the simulated modules gave; requests are the answers the clients read. The
//! clients are threads of the bench's own process on blocking loopback sockets.

use std::io::{Read, Write};
use std::net::TcpStream;
use std::process::{Command, Stdio};
use std::sync::Arc;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::time::Duration;

use pulsegate::sim::Plant;

use super::status_poll::{cpu_ns, median, reads};
use super::{Figure, Mosquitto, free_port, gateway_toml, tcp_plant, temp_dir};

const CLIENTS: u8 = 10;

/// The first address of the first channel block (enc0 of a YL67), and its length.
const BLOCK_AT: u16 = 20;
const BLOCK_LEN: u16 = 20;

/// Function 04 for `unit`'s first channel block, transaction 1.
fn request(unit: u8) -> [u8; 12] {
    let [a_hi, a_lo] = BLOCK_AT.to_be_bytes();
    let [n_hi, n_lo] = BLOCK_LEN.to_be_bytes();
    [0, 1, 0, 0, 0, 6, unit, 0x04, a_hi, a_lo, n_hi, n_lo]
}

/// One client while `on` is set: a connection, and the next read as soon as the last is
/// answered; every answer counted. A connection that fails is made again.
fn client(port: u16, unit: u8, on: Arc<AtomicBool>, stop: Arc<AtomicBool>, n: Arc<AtomicU64>) {
    std::thread::spawn(move || {
        let ask = request(unit);
        let mut answer = [0u8; 9 + 2 * BLOCK_LEN as usize];
        while !stop.load(Ordering::Relaxed) {
            if !on.load(Ordering::Relaxed) {
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
            let Ok(mut s) = TcpStream::connect(("127.0.0.1", port)) else {
                std::thread::sleep(Duration::from_millis(100));
                continue;
            };
            let _ = s.set_nodelay(true);
            let _ = s.set_read_timeout(Some(Duration::from_secs(5)));
            while on.load(Ordering::Relaxed) && !stop.load(Ordering::Relaxed) {
                if s.write_all(&ask).is_err() || s.read_exact(&mut answer).is_err() {
                    break;
                }
                if answer[7] == 0x04 {
                    n.fetch_add(1, Ordering::Relaxed);
                }
            }
        }
    });
}

/// One window of `secs`: the gateway's CPU seconds a second, the bus's transactions a
/// second, the requests answered a second.
async fn window(pid: u32, plant: &Plant, answered: &AtomicU64, secs: u64) -> (f64, f64, f64) {
    let (c0, t0, a0) = (cpu_ns(pid), reads(plant), answered.load(Ordering::Relaxed));
    tokio::time::sleep(Duration::from_secs(secs)).await;
    let (c1, t1, a1) = (cpu_ns(pid), reads(plant), answered.load(Ordering::Relaxed));
    let s = secs as f64;
    (
        (c1 - c0) as f64 / 1e9 / s,
        (t1 - t0) as f64 / s,
        (a1 - a0) as f64 / s,
    )
}

/// The gateway of this bench: the plant's 16 modules every 50 ms, JSON to Mosquitto, the
/// Modbus server on `port`.
fn start_gateway(
    plant: &Plant,
    sim: &pulsegate::sim::SimConfig,
    mqtt: u16,
    port: u16,
) -> std::process::Child {
    let dir = temp_dir("plc");
    let poll = std::env::var("BENCH_PLC_POLL").unwrap_or_else(|_| "50ms".into());
    let text = gateway_toml(plant, sim, 9600, &poll, &dir, &format!("port = {mqtt}"))
        + &format!(
            "[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\nlisten = \"127.0.0.1:{port}\"\n"
        );
    let path = dir.join("g.toml");
    std::fs::write(&path, text).unwrap();
    let bin = std::env::var("PULSEGATE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_pulsegate").to_string());
    Command::new(bin)
        .args(["run", "--config"])
        .arg(&path)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

fn env_or(name: &str, default: u64) -> u64 {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

pub async fn run(figures: &mut Vec<Figure>) {
    let rounds = env_or("BENCH_ROUNDS", 3);
    let secs = env_or("BENCH_PLC_SECS", 10);
    let mosquitto = Mosquitto::start();
    let sim = tcp_plant(1, 16);
    let plant = Plant::start(&sim).await.unwrap();
    let port = free_port();
    let mut child = start_gateway(&plant, &sim, mosquitto.1, port);
    let pid = child.id();
    let (on, stop) = (
        Arc::new(AtomicBool::new(false)),
        Arc::new(AtomicBool::new(false)),
    );
    let answered = Arc::new(AtomicU64::new(0));
    for unit in 1..=CLIENTS {
        client(port, unit, on.clone(), stop.clone(), answered.clone());
    }
    tokio::time::sleep(Duration::from_secs(5)).await;
    let (mut none, mut with) = (Vec::new(), Vec::new());
    for _ in 0..rounds {
        tokio::time::sleep(Duration::from_secs(1)).await;
        let quiet = window(pid, &plant, &answered, secs).await;
        on.store(true, Ordering::Relaxed);
        // The clients' first second stays out of the window.
        tokio::time::sleep(Duration::from_secs(1)).await;
        let busy = window(pid, &plant, &answered, secs).await;
        on.store(false, Ordering::Relaxed);
        println!(
            "plc: none {:.0} tx/s, {:.1}% CPU; 10 clients {:.0} requests/s, {:.0} tx/s, {:.1}% CPU: {:.1} us a request",
            quiet.1,
            quiet.0 * 100.0,
            busy.2,
            busy.1,
            busy.0 * 100.0,
            (busy.0 - quiet.0) * 1e6 / busy.2.max(1.0),
        );
        none.push(quiet);
        with.push(busy);
    }
    stop.store(true, Ordering::Relaxed);
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let _ = child.wait();
    drop(mosquitto);
    plant.stop();
    report(figures, &none, &with);
}

/// Medians over the rounds: requests a second, the CPU a request adds (the window's CPU less
/// the one without clients before it), the poll rate with clients over without.
fn report(figures: &mut Vec<Figure>, none: &[(f64, f64, f64)], with: &[(f64, f64, f64)]) {
    let per_request: Vec<f64> = none
        .iter()
        .zip(with)
        .map(|(n, w)| (w.0 - n.0) * 1e6 / w.2.max(1.0))
        .collect();
    let polls: Vec<f64> = none.iter().zip(with).map(|(n, w)| w.1 / n.1).collect();
    let spread = |v: &[f64]| {
        v.iter()
            .map(|x| format!("{x:.3}"))
            .collect::<Vec<_>>()
            .join(" ")
    };
    let requests = median(with.iter().map(|w| w.2).collect());
    let cpu = median(per_request.clone());
    let poll = median(polls.clone());
    let (tx_none, tx_with) = (
        median(none.iter().map(|n| n.1).collect()),
        median(with.iter().map(|w| w.1).collect()),
    );
    figures.push(Figure {
        what: "Modbus server, 10 clients as fast as answered: requests/s".into(),
        value: format!("{requests:.0} /s"),
        target: "(context)".into(),
        ratio: 1.0,
        pass: requests > 0.0,
    });
    figures.push(Figure {
        what: format!("Modbus server: CPU a request ({} us)", spread(&per_request)),
        value: format!("{cpu:.1} us"),
        target: "< 20 us".into(),
        ratio: cpu / 20.0,
        pass: cpu < 20.0,
    });
    figures.push(Figure {
        what: format!(
            "Modbus server: bus poll rate, 10 clients / none ({})",
            spread(&polls)
        ),
        value: format!("{tx_with:.0} / {tx_none:.0} tx/s"),
        target: ">= 0.95".into(),
        ratio: poll,
        pass: poll >= 0.95,
    });
}

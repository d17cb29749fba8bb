//! The anchors: the gateway's whole-process CPU per Modbus transaction against two bare
//! libmodbus clients in C that publish nothing, polling the same simulated plant in the same
//! run, everything pinned to one CPU. Each row pairs the gateway with the anchor that ran in
//! the same mode:
//! - pair A: the tight loop (`tight_loop.c`: libmodbus reads back to back in one process, no
//!   sleep) against the gateway polling as fast as answered;
//! - pair B: mbpoll's polling mode (`-l 10`: 10 ms of sleep after every unit) against the
//!   gateway paced to the rate mbpoll achieved.
//!
//! - One CPU (`BENCH_CPU`, default the last one) carries the simulator (this process, pinned with
//!   `taskset -a -p`), Mosquitto, the gateway and the anchor (both started under `taskset -c`).
//! - Transactions are counted by the simulated modules (FC03 answers), the same counter for every
//!   client; each row prints the transactions per second of both sides.
//! - CPU is the client's whole process, read from `/proc/PID/task/*/schedstat` (nanoseconds of
//!   CPU per thread) at the start and end of a fixed window; `/proc/PID/stat` (utime + stime, in
//!   10 ms ticks) is read too and printed beside it as a cross-check. No in-process timer.
//! - RTU: twin lines of each kind; the anchor polls one and the gateway the other in the same
//!   window (the lines pace both; host noise weighs on both), rounds swap the twins. TCP: the
//!   gateway polls as fast as answered and would starve the anchor, so rounds alternate the
//!   clients. `BENCH_ROUNDS` (default 3); the spread over rounds is printed.
//!
//! - The floor rows run `examples/rtu_floor.rs` (tokio-serial + tokio-modbus, with and without
//!   rumqttc publishing, back to back) in the gateway's place: what the card packages alone cost.
//!
//! mbpoll is the Debian package `mbpoll`, the tight loop needs `libmodbus-dev` and a C compiler
//! (`apt-get install mbpoll libmodbus-dev`). Without one of them this part says so and reports
//! the rows of that anchor as missed.

use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::Duration;

use pulsegate::sim::{Endpoint, Plant, SimConfig};

use super::{Figure, Mosquitto, temp_dir};

/// YL67 quadrature counts: the block mbpoll reads, and the first of the gateway's two reads.
const COUNT_REGISTER: u16 = 16;
const TCP_UNITS: u8 = 16;
const RTU_UNITS: u8 = 4;
const RTU_BAUD: u32 = 9600;

fn env_or<T: std::str::FromStr>(name: &str, default: T) -> T {
    std::env::var(name)
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(default)
}

/// The CPU everything runs on.
fn bench_cpu() -> usize {
    let cpus = std::thread::available_parallelism().map_or(1, |n| n.get());
    env_or("BENCH_CPU", cpus - 1)
}

/// Pins every thread of `pid` (and the threads they start later) to `cpus` (a taskset list).
fn pin(pid: u32, cpus: &str) {
    let ok = Command::new("taskset")
        .args(["-a", "-p", "-c", cpus, &pid.to_string()])
        .stdout(Stdio::null())
        .status()
        .is_ok_and(|s| s.success());
    assert!(ok, "taskset (util-linux) could not pin pid {pid} to {cpus}");
}

fn allowed_cpus() -> String {
    std::fs::read_to_string("/proc/self/status")
        .unwrap_or_default()
        .lines()
        .find_map(|l| l.strip_prefix("Cpus_allowed_list:"))
        .map(|v| v.trim().to_string())
        .unwrap_or_else(|| "0".into())
}

/// Whole-process CPU of `pid`: nanoseconds from every thread's schedstat, and the same from
/// `/proc/PID/stat` (utime + stime, 10 ms ticks, includes threads that have ended).
#[derive(Debug, Clone, Copy, Default)]
struct Cpu {
    sched_ns: u64,
    stat_ns: u64,
    /// Context switches (voluntary and not) of every thread: wake-ups, roughly.
    switches: u64,
}

fn cpu_of(pid: u32) -> Cpu {
    let mut sched_ns = 0;
    let mut switches = 0;
    if let Ok(tasks) = std::fs::read_dir(format!("/proc/{pid}/task")) {
        for t in tasks.flatten() {
            let status = std::fs::read_to_string(t.path().join("status")).unwrap_or_default();
            switches += status
                .lines()
                .filter(|l| l.contains("ctxt_switches:"))
                .filter_map(|l| l.split_whitespace().nth(1)?.parse::<u64>().ok())
                .sum::<u64>();
            let s = std::fs::read_to_string(t.path().join("schedstat")).unwrap_or_default();
            sched_ns += s
                .split_whitespace()
                .next()
                .and_then(|v| v.parse::<u64>().ok())
                .unwrap_or(0);
        }
    }
    let stat_ns = super::cpu_of(&pid.to_string()).as_nanos() as u64;
    Cpu {
        sched_ns,
        stat_ns,
        switches,
    }
}

/// FC03 answers given by the modules of `bus` so far.
fn reads(plant: &Plant, bus: &str) -> u64 {
    let b = plant.bus(bus).expect("bus of the plant");
    b.modules
        .lock()
        .unwrap_or_else(|e| e.into_inner())
        .values()
        .map(|m| m.reads)
        .sum()
}

/// One client measured over one window.
#[derive(Debug, Clone, Copy)]
struct Sample {
    cpu: Cpu,
    tx: u64,
    /// The window's length, seconds.
    secs: f64,
}

impl Sample {
    fn tx_per_s(&self) -> f64 {
        self.tx as f64 / self.secs
    }
    fn us_per_tx(&self) -> f64 {
        self.cpu.sched_ns as f64 / 1000.0 / self.tx.max(1) as f64
    }
    fn stat_us_per_tx(&self) -> f64 {
        self.cpu.stat_ns as f64 / 1000.0 / self.tx.max(1) as f64
    }
    fn switches_per_tx(&self) -> f64 {
        self.cpu.switches as f64 / self.tx.max(1) as f64
    }
}

/// Runs `child` for `warmup`, then measures it over `window`; stops it (SIGTERM) after.
async fn measure(
    child: Child,
    plant: &Plant,
    bus: &str,
    warmup: Duration,
    window: Duration,
) -> Sample {
    let mut c = Running::start(child);
    tokio::time::sleep(warmup).await;
    c.begin(plant, bus);
    tokio::time::sleep(window).await;
    c.end(plant, bus)
}

fn plant_config(dir: &Path) -> SimConfig {
    let mut t = String::from("[buses.hall]\nlisten = \"127.0.0.1:0\"\n");
    for u in 1..=TCP_UNITS {
        t += &format!(
            "[buses.hall.devices.t{u}]\nunit = {u}\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = 100.0 }}\n"
        );
    }
    // Twin RTU lines of each kind: mbpoll on one, the gateway on the other, in the same window.
    for (bus, trickle) in [
        ("line-a", false),
        ("line-b", false),
        ("trickle-a", true),
        ("trickle-b", true),
    ] {
        t += &format!(
            "[buses.{bus}]\nlink = {:?}\nline = {{ baud = {RTU_BAUD}, turnaround = \"{}ms\", trickle = {trickle} }}\n",
            dir.join(bus),
            super::TURNAROUND_MS
        );
        for u in 1..=RTU_UNITS {
            t += &format!(
                "[buses.{bus}.devices.{bus}-{u}]\nunit = {u}\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = 100.0 }}\n"
            );
        }
    }
    SimConfig::from_toml(&t).unwrap()
}

/// Gateway config polling one bus of the plant as fast as it answers, per-channel (or
/// per-device) JSON at QoS 1.
fn gateway_config(
    dir: &Path,
    name: &str,
    endpoint: &Endpoint,
    units: u8,
    broker: u16,
    per_device: bool,
    poll: &str,
) -> PathBuf {
    let state = dir.join(format!("state-{name}"));
    let payload = if per_device { "device" } else { "channel" };
    let mut t = format!(
        "[gateway]\nid = \"bench\"\nstate_dir = {state:?}\nstats_interval = \"1h\"\npayload = \"{payload}\"\n[mqtt]\nhost = \"127.0.0.1\"\nport = {broker}\nqos = 1\n"
    );
    let prefix = match endpoint {
        Endpoint::Serial(p) => {
            t += &format!("[buses.b]\nport = {p:?}\nbaud = {RTU_BAUD}\ntimeout = \"100ms\"\n");
            'r'
        }
        Endpoint::Tcp(a) => {
            t += &format!(
                "[buses.b]\nhost = \"{}\"\nport = {}\ntimeout = \"100ms\"\n",
                a.ip(),
                a.port()
            );
            't'
        }
    };
    for u in 1..=units {
        t += &format!(
            "[buses.b.devices.{prefix}{u}]\nunit = {u}\nmodel = \"yl67\"\npoll = \"{poll}\"\n"
        );
    }
    let path = dir.join(format!("{name}.toml"));
    std::fs::write(&path, t).unwrap();
    path
}

fn gateway(config: &Path, cpu: usize) -> Child {
    let bin = std::env::var("PULSEGATE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_pulsegate").to_string());
    Command::new("taskset")
        .args(["-c", &cpu.to_string()])
        .arg(bin)
        .args(["run", "--config"])
        .arg(config)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// mbpoll reading the count block of every unit in turn, forever (`-l 10`: its shortest pause
/// between reads). Its output goes to a pipe read by a thread here (block-buffered by its
/// stdio, as it would be in any script).
fn mbpoll(endpoint: &Endpoint, units: u8, cpu: usize) -> Child {
    let mut c = Command::new("taskset");
    c.args(["-c", &cpu.to_string(), "mbpoll"]);
    let count = COUNT_REGISTER.to_string();
    let addresses = format!("1:{units}");
    c.args([
        "-0", "-r", &count, "-c", "8", "-t", "4", "-l", "10", "-o", "0.1",
    ]);
    c.args(["-a", &addresses]);
    match endpoint {
        Endpoint::Tcp(a) => {
            c.args([
                "-m",
                "tcp",
                "-p",
                &a.port().to_string(),
                &a.ip().to_string(),
            ]);
        }
        Endpoint::Serial(p) => {
            c.args(["-m", "rtu", "-b", &RTU_BAUD.to_string(), "-P", "none"]);
            c.arg(p);
        }
    }
    let mut child = c
        .stdin(Stdio::null())
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let mut out = child.stdout.take().unwrap();
    std::thread::spawn(move || std::io::copy(&mut out, &mut std::io::sink()));
    child
}

fn have_mbpoll() -> bool {
    Command::new("mbpoll")
        .arg("-V")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .status()
        .is_ok()
}

/// How long the tight loop runs if nothing stops it (the bench stops it after its window).
const TIGHT_LOOP_SECS: u32 = 600;

/// Compiles `tight_loop.c` against libmodbus into the target dir; `None` (said, with how to
/// install what is missing) if it cannot.
fn tight_loop_binary() -> Option<PathBuf> {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let out = target_dir().join("bench-tools");
    let path = out.join("tight_loop");
    let flags = Command::new("pkg-config")
        .args(["--cflags", "--libs", "libmodbus"])
        .output()
        .ok()
        .filter(|o| o.status.success())
        .map(|o| String::from_utf8_lossy(&o.stdout).into_owned())
        .unwrap_or_else(|| "-I/usr/include/modbus -lmodbus".into());
    let built = std::fs::create_dir_all(&out).is_ok()
        && Command::new("cc")
            .args(["-O2", "-Wall", "-o"])
            .arg(&path)
            .arg(manifest.join("benches/line/tight_loop.c"))
            .args(flags.split_whitespace())
            .status()
            .is_ok_and(|s| s.success());
    if !built {
        println!(
            "\nthe tight loop (benches/line/tight_loop.c) could not be built: it needs a C compiler \
             and libmodbus. Install the Debian package: `sudo apt-get install libmodbus-dev`, then \
             run `cargo bench --bench line mbpoll` again. Its rows are reported as missed."
        );
        return None;
    }
    Some(path)
}

/// The tight loop reading the count block of every unit in turn, back to back.
fn tight_loop(binary: &Path, endpoint: &Endpoint, units: u8, cpu: usize) -> Child {
    let mut c = Command::new("taskset");
    c.args(["-c", &cpu.to_string()]).arg(binary);
    match endpoint {
        Endpoint::Tcp(a) => c.args(["tcp".into(), a.ip().to_string(), a.port().to_string()]),
        Endpoint::Serial(p) => c.arg("rtu").arg(p).arg(RTU_BAUD.to_string()),
    };
    c.args([
        units.to_string(),
        COUNT_REGISTER.to_string(),
        TIGHT_LOOP_SECS.to_string(),
    ]);
    c.stdin(Stdio::null())
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// The client a row's gateway is measured against, named by the mode it runs in.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Anchor {
    /// mbpoll's polling mode (`-l 10`): 10 ms of sleep after every unit.
    Polling,
    /// `tight_loop.c`: libmodbus reads back to back in one process, no sleep.
    TightLoop,
}

impl Anchor {
    fn mode(self) -> &'static str {
        match self {
            Anchor::Polling => "mbpoll polling mode (-l 10)",
            Anchor::TightLoop => "tight loop (libmodbus, back to back)",
        }
    }
}

/// The anchors this machine has.
struct Anchors {
    mbpoll: bool,
    tight_loop: Option<PathBuf>,
}

impl Anchors {
    fn find() -> Anchors {
        let mbpoll = have_mbpoll();
        if !mbpoll {
            println!(
                "\nmbpoll is missing: the polling-mode rows need it. Install the Debian package: \
                 `sudo apt-get install mbpoll` (https://github.com/epsilonrt/mbpoll), then run \
                 `cargo bench --bench line mbpoll` again. Its rows are reported as missed."
            );
        }
        Anchors {
            mbpoll,
            tight_loop: tight_loop_binary(),
        }
    }

    fn has(&self, anchor: Anchor) -> bool {
        match anchor {
            Anchor::Polling => self.mbpoll,
            Anchor::TightLoop => self.tight_loop.is_some(),
        }
    }

    fn start(&self, anchor: Anchor, endpoint: &Endpoint, units: u8, cpu: usize) -> Child {
        match (anchor, &self.tight_loop) {
            (Anchor::TightLoop, Some(binary)) => tight_loop(binary, endpoint, units, cpu),
            (Anchor::TightLoop, None) => panic!("the tight loop was not built"),
            (Anchor::Polling, _) => mbpoll(endpoint, units, cpu),
        }
    }
}

/// The rounds of one comparison: (gateway or floor client, anchor) samples.
type Rounds = Vec<(Sample, Sample)>;

/// One row of the report: what the gateway (or floor client) polls and how, and its anchor.
struct Scenario {
    what: &'static str,
    /// The mode the gateway (or the floor client) ran in.
    client: &'static str,
    anchor: Anchor,
    /// Held to the target (no more CPU a transaction than the anchor); else context.
    target: bool,
}

const FULL: &str = "pulsegate as fast as answered";
const PACED: &str = "pulsegate paced to mbpoll's rate";
const FLOOR: &str = "floor client as fast as answered";

fn median(mut v: Vec<f64>) -> f64 {
    v.sort_by(f64::total_cmp);
    v[v.len() / 2]
}

fn summary(row: &Scenario, rounds: &Rounds, figures: &mut Vec<Figure>) {
    let (client, anchor) = (row.client, row.anchor.mode());
    let ratios: Vec<f64> = rounds
        .iter()
        .map(|(g, m)| g.us_per_tx() / m.us_per_tx())
        .collect();
    for (i, (g, m)) in rounds.iter().enumerate() {
        println!(
            "  {}, round {}: {client} {:.1} us/tx at {:.1} tx/s ({} tx; /proc/PID/stat {:.1}; {:.1} switches/tx), {anchor} {:.1} us/tx at {:.1} tx/s ({} tx; stat {:.1}; {:.1} switches/tx), ratio {:.3}",
            row.what,
            i + 1,
            g.us_per_tx(),
            g.tx_per_s(),
            g.tx,
            g.stat_us_per_tx(),
            g.switches_per_tx(),
            m.us_per_tx(),
            m.tx_per_s(),
            m.tx,
            m.stat_us_per_tx(),
            m.switches_per_tx(),
            ratios[i]
        );
    }
    let of = |f: &dyn Fn(&(Sample, Sample)) -> f64| median(rounds.iter().map(f).collect());
    let (lo, hi) = ratios
        .iter()
        .fold((f64::MAX, f64::MIN), |(l, h), r| (l.min(*r), h.max(*r)));
    figures.push(Figure {
        what: format!("{}: {client} / {anchor}, CPU/tx", row.what),
        value: format!(
            "{:.0} / {:.0} us at {:.0} / {:.0} tx/s ({lo:.2}-{hi:.2})",
            of(&|r| r.0.us_per_tx()),
            of(&|r| r.1.us_per_tx()),
            of(&|r| r.0.tx_per_s()),
            of(&|r| r.1.tx_per_s()),
        ),
        target: match row.target {
            true => format!("<= 1.0 (median of {})", ratios.len()),
            false => format!("(context, median of {})", ratios.len()),
        },
        ratio: median(ratios.clone()),
        pass: !row.target || median(ratios) <= 1.0,
    });
}

/// The comparisons, in report order (the indices below name them).
const SCENARIOS: [Scenario; 11] = [
    Scenario {
        what: "pair A, Modbus TCP, 16 YL67, per-channel JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: true,
    },
    Scenario {
        what: "pair A, Modbus TCP, 16 YL67, per-device JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: true,
    },
    Scenario {
        what: "pair B, Modbus TCP, 16 YL67, per-channel JSON QoS 1",
        client: PACED,
        anchor: Anchor::Polling,
        target: true,
    },
    Scenario {
        what: "pair A, Modbus RTU 9600, 4 YL67, frames at once, per-channel JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: true,
    },
    Scenario {
        what: "pair B, Modbus RTU 9600, 4 YL67, frames at once, per-channel JSON QoS 1",
        client: PACED,
        anchor: Anchor::Polling,
        target: true,
    },
    Scenario {
        what: "Modbus RTU 9600, 4 YL67, bytes trickling, per-channel JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: true,
    },
    Scenario {
        what: "Modbus RTU 9600, 4 YL67, bytes trickling, per-device JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: true,
    },
    Scenario {
        what: "Modbus RTU 9600, 4 YL67, frames at once, per-channel JSON QoS 1, broker on a Unix socket",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: false,
    },
    Scenario {
        what: "floor: tokio-serial + tokio-modbus alone, RTU 9600, frames at once, no MQTT",
        client: FLOOR,
        anchor: Anchor::TightLoop,
        target: false,
    },
    Scenario {
        what: "floor: tokio-serial + tokio-modbus + rumqttc, RTU 9600, frames at once, 4 messages a poll QoS 1",
        client: FLOOR,
        anchor: Anchor::TightLoop,
        target: false,
    },
    Scenario {
        what: "context: pulsegate with mqtt.batch = \"0s\" (each poll at once), RTU 9600, bytes trickling, per-channel JSON QoS 1",
        client: FULL,
        anchor: Anchor::TightLoop,
        target: false,
    },
];

const TCP_FULL: usize = 0;
const TCP_PACED: usize = 2;
const RTU_FULL: usize = 3;
const RTU_PACED: usize = 4;
const TRICKLE: usize = 5;
const TRICKLE_DEVICE: usize = 6;
const UNIX_SOCKET: usize = 7;
const FLOORS: usize = 8;
const UNBATCHED: usize = 10;

/// Transactions in one poll of a YL67 in quadrature mode: the count block and the frequency
/// block (8 registers each).
const YL67_READS_A_POLL: f64 = 2.0;

/// The gateway's poll interval that makes `rate` transactions a second over `units` YL67.
fn poll_for(rate: f64, units: u8) -> String {
    let ms = f64::from(units) * YL67_READS_A_POLL / rate.max(1.0) * 1000.0;
    format!("{}ms", ms as u64)
}

fn missed(row: &Scenario) -> Figure {
    Figure {
        what: format!(
            "{}: {} / {}, CPU/tx",
            row.what,
            row.client,
            row.anchor.mode()
        ),
        value: format!("{} missing", row.anchor.mode()),
        target: "<= 1.0".into(),
        ratio: f64::NAN,
        pass: false,
    }
}

/// The side-by-side comparison (bench part `mbpoll`).
pub async fn run(figures: &mut Vec<Figure>) {
    let anchors = Anchors::find();
    let cpu = bench_cpu();
    let before = allowed_cpus();
    let rounds: usize = env_or("BENCH_ROUNDS", 3);
    let tcp_window = Duration::from_secs(env_or("BENCH_TCP_SECS", 10));
    let rtu_window = Duration::from_secs(env_or("BENCH_RTU_SECS", 15));
    println!(
        "\nside by side with the anchors on CPU {cpu}: {rounds} rounds, windows {}s (TCP) / {}s (RTU)",
        tcp_window.as_secs(),
        rtu_window.as_secs()
    );
    // The simulator (this process's runtime and the line emulator's threads, started below)
    // runs on the same CPU as the clients and the broker.
    pin(std::process::id(), &cpu.to_string());
    let dir = temp_dir("mbpoll");
    let mosquitto = Mosquitto::start();
    pin(mosquitto.0.id(), &cpu.to_string());
    let plant = Plant::start(&plant_config(&dir)).await.unwrap();
    let socket = mosquitto.socket();
    let tcp = TcpRound {
        plant: &plant,
        dir: &dir,
        endpoint: plant.bus("hall").unwrap().endpoint.clone(),
        broker: mosquitto.1,
        anchors: &anchors,
        cpu,
        window: tcp_window,
    };
    let rtu = RtuTwins {
        plant: &plant,
        dir: &dir,
        kind: "line",
        broker: mosquitto.1,
        socket: None,
        unbatched: false,
        poll: "1ms",
        anchor: Anchor::TightLoop,
        anchors: &anchors,
        cpu,
    };
    let mut results: Vec<Rounds> = vec![Vec::new(); SCENARIOS.len()];
    // BENCH_SIDE=rtu (or tcp) measures one side only, when working on it.
    let side = std::env::var("BENCH_SIDE").unwrap_or_default();
    let floor = if side == "tcp" { None } else { floor_binary() };
    let paced = match side != "tcp" && anchors.mbpoll {
        true => rtu_paced_poll(&rtu).await,
        false => String::new(),
    };
    for round in 0..rounds {
        if side != "rtu" {
            tcp.round(&mut results).await;
        }
        if side != "tcp" {
            let ways = (paced.as_str(), socket.as_path(), floor.as_deref());
            rtu_round(rtu, ways, round, rtu_window, &mut results).await;
        }
    }
    for (row, rounds) in SCENARIOS.iter().zip(&results) {
        match rounds.is_empty() {
            false => summary(row, rounds, figures),
            true if !anchors.has(row.anchor) => figures.push(missed(row)),
            true => {}
        }
    }
    drop(plant);
    drop(mosquitto);
    pin(std::process::id(), &before);
}

/// The poll interval that paces the RTU gateway to mbpoll's rate: mbpoll alone on a
/// frames-at-once line for a few seconds, before the rounds.
async fn rtu_paced_poll(twins: &RtuTwins<'_>) -> String {
    let endpoint = twins
        .plant
        .bus("line-a")
        .expect("twin line")
        .endpoint
        .clone();
    settle(&endpoint).await;
    let child = mbpoll(&endpoint, RTU_UNITS, twins.cpu);
    let warmup = Duration::from_secs(2);
    let m = measure(child, twins.plant, "line-a", warmup, Duration::from_secs(6)).await;
    let poll = poll_for(m.tx_per_s(), RTU_UNITS);
    println!(
        "  mbpoll polling mode on RTU 9600 frames at once: {:.1} tx/s; the paced gateway polls every {poll}",
        m.tx_per_s()
    );
    poll
}

/// One round of the RTU comparisons: twins of each kind, then the floors.
async fn rtu_round(
    base: RtuTwins<'_>,
    (paced, socket, floor): (&str, &Path, Option<&Path>),
    round: usize,
    window: Duration,
    results: &mut [Rounds],
) {
    let line = base;
    let trickle = RtuTwins {
        kind: "trickle",
        ..base
    };
    let rows = [
        (RTU_FULL, line, false),
        (
            RTU_PACED,
            RtuTwins {
                poll: paced,
                anchor: Anchor::Polling,
                ..line
            },
            false,
        ),
        (TRICKLE, trickle, false),
        (TRICKLE_DEVICE, trickle, true),
        (
            UNIX_SOCKET,
            RtuTwins {
                socket: Some(socket),
                ..line
            },
            false,
        ),
        (
            UNBATCHED,
            RtuTwins {
                unbatched: true,
                ..trickle
            },
            false,
        ),
    ];
    for (row, twins, per_device) in rows {
        if base.anchors.has(twins.anchor) {
            results[row].push(twins.measure(per_device, round, window).await);
        }
    }
    let Some(floor) = floor.filter(|_| base.anchors.has(line.anchor)) else {
        return;
    };
    for (i, mqtt) in [None, Some(base.broker)].into_iter().enumerate() {
        let start = |p: &Endpoint| floor_client(floor, p, mqtt, base.cpu);
        let pair = line.measure_client(start, round, window).await;
        results[FLOORS + i].push(pair);
    }
}

/// Twin RTU lines of one kind (`line-a`/`line-b`: frames at once, `trickle-a`/`trickle-b`:
/// bytes at character pace): the anchor polls one and the gateway the other, started together and
/// measured over the same window. The lines pace both clients (neither can take the CPU from
/// the other), and whatever else the machine does in that window weighs on both: alternating
/// windows gave ratios that moved ±50% between rounds. Rounds swap the twins.
#[derive(Clone, Copy)]
struct RtuTwins<'a> {
    plant: &'a Plant,
    dir: &'a Path,
    kind: &'a str,
    broker: u16,
    /// The gateway reaches the broker over this Unix socket rather than loopback TCP.
    socket: Option<&'a Path>,
    /// The gateway sends each poll's readings at once (`mqtt.batch = "0s"`).
    unbatched: bool,
    /// The gateway's poll interval (`1ms`: as fast as answered).
    poll: &'a str,
    anchor: Anchor,
    anchors: &'a Anchors,
    cpu: usize,
}

impl RtuTwins<'_> {
    async fn measure(&self, per_device: bool, round: usize, window: Duration) -> (Sample, Sample) {
        let start = |endpoint: &Endpoint| {
            let name = format!(
                "{}-{round}-{}{}{}-{}",
                self.kind,
                if per_device { "dev" } else { "ch" },
                if self.socket.is_some() { "-unix" } else { "" },
                if self.unbatched { "-unbatched" } else { "" },
                self.poll
            );
            let config = gateway_config(
                self.dir,
                &name,
                endpoint,
                RTU_UNITS,
                self.broker,
                per_device,
                self.poll,
            );
            if let Some(socket) = self.socket {
                set_mqtt(&config, &format!("socket = {socket:?}"));
            }
            if self.unbatched {
                set_mqtt(&config, "batch = \"0s\"");
            }
            gateway(&config, self.cpu)
        };
        self.measure_client(start, round, window).await
    }

    /// `start`s a client on one twin and the anchor on the other; both measured in one window.
    async fn measure_client(
        &self,
        start: impl FnOnce(&Endpoint) -> Child,
        round: usize,
        window: Duration,
    ) -> (Sample, Sample) {
        let (mine, theirs) = if round % 2 == 0 {
            ("b", "a")
        } else {
            ("a", "b")
        };
        let gw_bus = format!("{}-{mine}", self.kind);
        let mb_bus = format!("{}-{theirs}", self.kind);
        let endpoint = |bus: &str| self.plant.bus(bus).expect("twin line").endpoint.clone();
        settle(&endpoint(&gw_bus)).await;
        settle(&endpoint(&mb_bus)).await;
        let mut g = Running::start(start(&endpoint(&gw_bus)));
        let anchor = self
            .anchors
            .start(self.anchor, &endpoint(&mb_bus), RTU_UNITS, self.cpu);
        let mut m = Running::start(anchor);
        tokio::time::sleep(Duration::from_secs(3)).await;
        g.begin(self.plant, &gw_bus);
        m.begin(self.plant, &mb_bus);
        tokio::time::sleep(window).await;
        (g.end(self.plant, &gw_bus), m.end(self.plant, &mb_bus))
    }
}

/// Empties what a stopped client left on an RTU line. An answer on its way when the client was
/// stopped would be read by the next one as the answer to its first request, and each answer
/// after it one request early: its pauses then hide behind the line (mbpoll's polling mode
/// measured 31 tx/s, the line's limit, instead of its own ~24).
async fn settle(endpoint: &Endpoint) {
    let Endpoint::Serial(path) = endpoint else {
        return;
    };
    // Longer than the longest answer's line time (21 characters at 9600 baud) and turnaround.
    tokio::time::sleep(Duration::from_millis(100)).await;
    match serialport::new(path.to_string_lossy(), RTU_BAUD).open() {
        Ok(port) => {
            if let Err(e) = port.clear(serialport::ClearBuffer::Input) {
                println!("  could not empty {path:?} before a window: {e}");
            }
        }
        Err(e) => println!("  could not open {path:?} to empty it before a window: {e}"),
    }
}

/// Adds `line` to the `[mqtt]` table of the gateway `config` (`socket = …`: host and port are
/// then not used).
fn set_mqtt(config: &Path, line: &str) {
    let text = std::fs::read_to_string(config).expect("gateway config");
    assert!(
        text.contains("[mqtt]\n"),
        "gateway config without an [mqtt] table"
    );
    let text = text.replacen("[mqtt]\n", &format!("[mqtt]\n{line}\n"), 1);
    std::fs::write(config, text).expect("gateway config");
}

/// Where cargo builds: `CARGO_TARGET_DIR`, else `target/` of the manifest.
fn target_dir() -> PathBuf {
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    std::env::var("CARGO_TARGET_DIR").map_or_else(|_| manifest.join("target"), PathBuf::from)
}

/// Builds `examples/rtu_floor.rs` (release) and returns its path; `None` (said) if it cannot.
fn floor_binary() -> Option<PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let built = Command::new(cargo)
        .args(["build", "--release", "--quiet", "--example", "rtu_floor"])
        .current_dir(manifest)
        .status()
        .is_ok_and(|s| s.success());
    let path = target_dir().join("release/examples/rtu_floor");
    if !built || !path.exists() {
        println!(
            "\nthe floor client (examples/rtu_floor.rs) could not be built: its rows are left out"
        );
        return None;
    }
    Some(path)
}

/// The floor client on `endpoint` (an RTU line), publishing to the broker at `mqtt` if given.
fn floor_client(binary: &Path, endpoint: &Endpoint, mqtt: Option<u16>, cpu: usize) -> Child {
    let Endpoint::Serial(port) = endpoint else {
        panic!("the floor client polls an RTU line")
    };
    let mut c = Command::new("taskset");
    c.args(["-c", &cpu.to_string()]).arg(binary).arg(port);
    if let Some(mqtt) = mqtt {
        c.arg(mqtt.to_string());
    }
    c.stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap()
}

/// A client being measured: CPU, transactions and time at the window's start.
struct Running {
    child: Child,
    start: (Cpu, u64, std::time::Instant),
}

impl Running {
    fn start(child: Child) -> Running {
        Running {
            child,
            start: (Cpu::default(), 0, std::time::Instant::now()),
        }
    }

    fn begin(&mut self, plant: &Plant, bus: &str) {
        let at = std::time::Instant::now();
        self.start = (cpu_of(self.child.id()), reads(plant, bus), at);
    }

    /// The window's figures; stops the client (SIGTERM).
    fn end(mut self, plant: &Plant, bus: &str) -> Sample {
        let (c1, r1) = (cpu_of(self.child.id()), reads(plant, bus));
        let secs = self.start.2.elapsed().as_secs_f64();
        let _ = Command::new("kill")
            .args(["-TERM", &self.child.id().to_string()])
            .status();
        let _ = self.child.wait();
        let c0 = self.start.0;
        Sample {
            cpu: Cpu {
                sched_ns: c1.sched_ns.saturating_sub(c0.sched_ns),
                stat_ns: c1.stat_ns.saturating_sub(c0.stat_ns),
                switches: c1.switches.saturating_sub(c0.switches),
            },
            tx: r1 - self.start.1,
            secs,
        }
    }
}

/// The TCP side of one run: rounds alternate the clients on the one TCP bus.
struct TcpRound<'a> {
    plant: &'a Plant,
    dir: &'a Path,
    endpoint: Endpoint,
    broker: u16,
    anchors: &'a Anchors,
    cpu: usize,
    window: Duration,
}

impl TcpRound<'_> {
    /// Measures `child` on the TCP bus over one window.
    async fn measure(&self, child: Child, warmup: Duration) -> Sample {
        measure(child, self.plant, "hall", warmup, self.window).await
    }

    fn gateway(&self, name: &str, per_device: bool, poll: &str) -> Child {
        let units = TCP_UNITS;
        let config = gateway_config(
            self.dir,
            name,
            &self.endpoint,
            units,
            self.broker,
            per_device,
            poll,
        );
        gateway(&config, self.cpu)
    }

    /// One round: pair A (tight loop, then the gateway as fast as answered, per channel and
    /// per device), pair B (mbpoll polling, then the gateway paced to the rate mbpoll made).
    async fn round(&self, results: &mut [Rounds]) {
        let warmup = Duration::from_secs(3);
        let short = Duration::from_secs(1);
        let (cpu, units) = (self.cpu, TCP_UNITS);
        if self.anchors.has(Anchor::TightLoop) {
            let anchor = self
                .anchors
                .start(Anchor::TightLoop, &self.endpoint, units, cpu);
            let m = self.measure(anchor, short).await;
            for (i, per_device) in [false, true].into_iter().enumerate() {
                let name = if per_device { "tcp-dev" } else { "tcp-ch" };
                let g = self.measure(self.gateway(name, per_device, "1ms"), warmup);
                results[TCP_FULL + i].push((g.await, m));
            }
        }
        if self.anchors.has(Anchor::Polling) {
            let m = self
                .measure(mbpoll(&self.endpoint, units, cpu), short)
                .await;
            // Every transaction pays its own wake-ups, as mbpoll's do.
            let poll = poll_for(m.tx_per_s(), units);
            let g = self.measure(self.gateway("tcp-paced", false, &poll), warmup);
            results[TCP_PACED].push((g.await, m));
        }
    }
}

//! The anchor: the gateway's whole-process CPU per Modbus transaction against mbpoll's (a bare
//! libmodbus client in C that publishes nothing), polling the same simulated plant in the same
//! run, everything pinned to one CPU.
//!
//! - One CPU (`BENCH_CPU`, default the last one) carries the simulator (this process, pinned with
//!   `taskset -a -p`), Mosquitto, the gateway and mbpoll (both started under `taskset -c`).
//! - Transactions are counted by the simulated modules (FC03 answers), the same counter for both
//!   clients.
//! - CPU is the client's whole process, read from `/proc/PID/task/*/schedstat` (nanoseconds of
//!   CPU per thread) at the start and end of a fixed window; `/proc/PID/stat` (utime + stime, in
//!   10 ms ticks) is read too and printed beside it as a cross-check. No in-process timer.
//! - RTU: twin lines of each kind; mbpoll polls one and the gateway the other in the same
//!   window (the lines pace both; host noise weighs on both), rounds swap the twins. TCP: the
//!   gateway polls as fast as answered and would starve mbpoll, so rounds alternate the clients.
//!   `BENCH_ROUNDS` (default 3); the spread over rounds is printed.
//!
//! - The floor rows run `examples/rtu_floor.rs` (tokio-serial + tokio-modbus, with and without
//!   rumqttc publishing) in the gateway's place: what the card packages alone cost.
//!
//! mbpoll is the Debian package `mbpoll` (`apt-get install mbpoll`). Without it this part says so
//! and reports the figures as missed.

use std::path::Path;
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
}

impl Sample {
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
) -> std::path::PathBuf {
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

/// The rounds of one comparison: (gateway, mbpoll) samples.
type Rounds = Vec<(Sample, Sample)>;

fn summary(what: &str, rounds: &Rounds, figures: &mut Vec<Figure>, target: Option<f64>) {
    let client = if what.starts_with("floor") {
        "floor"
    } else {
        "pulsegate"
    };
    let mut ratios: Vec<f64> = rounds
        .iter()
        .map(|(g, m)| g.us_per_tx() / m.us_per_tx())
        .collect();
    for (i, (g, m)) in rounds.iter().enumerate() {
        println!(
            "  {what}, round {}: {client} {:.1} us/tx ({} tx; /proc/PID/stat {:.1}; {:.1} switches/tx), mbpoll {:.1} us/tx ({} tx; stat {:.1}; {:.1} switches/tx), ratio {:.3}",
            i + 1,
            g.us_per_tx(),
            g.tx,
            g.stat_us_per_tx(),
            g.switches_per_tx(),
            m.us_per_tx(),
            m.tx,
            m.stat_us_per_tx(),
            m.switches_per_tx(),
            ratios[i]
        );
    }
    ratios.sort_by(f64::total_cmp);
    let median = ratios[ratios.len() / 2];
    let median_of = |f: &dyn Fn(&(Sample, Sample)) -> f64| {
        let mut v: Vec<f64> = rounds.iter().map(f).collect();
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let g = median_of(&|r| r.0.us_per_tx());
    let m = median_of(&|r| r.1.us_per_tx());
    figures.push(Figure {
        what: format!("{what}: CPU/tx {client} / mbpoll"),
        value: format!(
            "{g:.0} / {m:.0} us ({:.2}-{:.2})",
            ratios[0],
            ratios[ratios.len() - 1]
        ),
        target: match target {
            Some(t) => format!("<= {t:.1} (median of {})", ratios.len()),
            None => format!("(context, median of {})", ratios.len()),
        },
        ratio: median,
        pass: target.is_none_or(|t| median <= t),
    });
}

/// The comparisons, in report order.
const SCENARIOS: [&str; 10] = [
    "Modbus TCP, 16 YL67, as fast as answered, per-channel JSON QoS 1",
    "Modbus TCP, 16 YL67, as fast as answered, per-device JSON QoS 1",
    "Modbus TCP, 16 YL67, at mbpoll's rate, per-channel JSON QoS 1",
    "Modbus RTU 9600, 4 YL67, frames at once, per-channel JSON QoS 1",
    "Modbus RTU 9600, 4 YL67, bytes trickling, per-channel JSON QoS 1",
    "Modbus RTU 9600, 4 YL67, bytes trickling, per-device JSON QoS 1",
    "Modbus RTU 9600, 4 YL67, frames at once, per-channel JSON QoS 1, broker on a Unix socket",
    "floor: tokio-serial + tokio-modbus alone, RTU 9600, frames at once, no MQTT",
    "floor: tokio-serial + tokio-modbus + rumqttc, RTU 9600, frames at once, 4 messages a poll QoS 1",
    "context: pulsegate with mqtt.batch = \"0s\" (each poll at once), RTU 9600, bytes trickling, per-channel JSON QoS 1",
];

/// The context row that measures the gateway without its batch.
const UNBATCHED: usize = 9;

/// The scenarios from here on are printed for context (no target): floors, and the gateway
/// without its batch.
const FLOORS_FROM: usize = 7;

/// Transactions in one poll of a YL67 in quadrature mode: the count block and the frequency
/// block (8 registers each).
const YL67_READS_A_POLL: f64 = 2.0;

fn missing(figures: &mut Vec<Figure>) {
    println!(
        "\nmbpoll is missing: the side-by-side figures need it. Install the Debian package: \
         `sudo apt-get install mbpoll` (https://github.com/epsilonrt/mbpoll), then run \
         `cargo bench --bench line mbpoll` again."
    );
    for what in SCENARIOS {
        figures.push(Figure {
            what: format!("{what}: CPU/tx pulsegate / mbpoll"),
            value: "mbpoll missing".into(),
            target: "<= 1.0".into(),
            ratio: f64::NAN,
            pass: false,
        });
    }
}

/// The side-by-side comparison (bench part `mbpoll`).
pub async fn run(figures: &mut Vec<Figure>) {
    if !have_mbpoll() {
        missing(figures);
        return;
    }
    let cpu = bench_cpu();
    let before = allowed_cpus();
    let rounds: usize = env_or("BENCH_ROUNDS", 3);
    let tcp_window = Duration::from_secs(env_or("BENCH_TCP_SECS", 10));
    let rtu_window = Duration::from_secs(env_or("BENCH_RTU_SECS", 15));
    println!(
        "\nside by side with mbpoll on CPU {cpu}: {rounds} rounds, windows {}s (TCP) / {}s (RTU)",
        tcp_window.as_secs(),
        rtu_window.as_secs()
    );
    // The simulator (this process's runtime and the line emulator's threads, started below)
    // runs on the same CPU as the clients and the broker.
    pin(std::process::id(), &cpu.to_string());
    let dir = temp_dir("mbpoll");
    let mosquitto = Mosquitto::start();
    pin(mosquitto.0.id(), &cpu.to_string());
    let sim = plant_config(&dir);
    let plant = Plant::start(&sim).await.unwrap();
    let endpoint = |bus: &str| plant.bus(bus).unwrap().endpoint.clone();
    let tcp = endpoint("hall");
    let broker = mosquitto.1;
    let configs = [
        gateway_config(&dir, "tcp-ch", &tcp, TCP_UNITS, broker, false, "1ms"),
        gateway_config(&dir, "tcp-dev", &tcp, TCP_UNITS, broker, true, "1ms"),
    ];
    let mut results: Vec<Rounds> = vec![Vec::new(); SCENARIOS.len()];
    // BENCH_SIDE=rtu (or tcp) measures one side only, when working on it.
    let side = std::env::var("BENCH_SIDE").unwrap_or_default();
    let floor = if side == "tcp" { None } else { floor_binary() };
    for round in 0..rounds {
        if side != "rtu" {
            tcp_rounds(
                &plant,
                &dir,
                &configs,
                &tcp,
                broker,
                cpu,
                tcp_window,
                &mut results,
            )
            .await;
        }
        if side == "tcp" {
            continue;
        }
        let socket = mosquitto.socket();
        let rtu = [
            ("line", false, None),
            ("trickle", false, None),
            ("trickle", true, None),
            ("line", false, Some(socket.as_path())),
        ];
        for (i, (kind, per_device, socket)) in rtu.into_iter().enumerate() {
            let twins = RtuTwins {
                plant: &plant,
                dir: &dir,
                kind,
                broker,
                socket,
                unbatched: false,
                cpu,
            };
            results[3 + i].push(twins.measure(per_device, round, rtu_window).await);
        }
        if let Some(floor) = &floor {
            let twins = RtuTwins {
                plant: &plant,
                dir: &dir,
                kind: "line",
                broker,
                socket: None,
                unbatched: false,
                cpu,
            };
            for (i, mqtt) in [None, Some(broker)].into_iter().enumerate() {
                let start = |p: &Endpoint| floor_client(floor, p, mqtt, cpu);
                let pair = twins.measure_client(start, round, rtu_window).await;
                results[FLOORS_FROM + i].push(pair);
            }
        }
        let twins = RtuTwins {
            plant: &plant,
            dir: &dir,
            kind: "trickle",
            broker,
            socket: None,
            unbatched: true,
            cpu,
        };
        results[UNBATCHED].push(twins.measure(false, round, rtu_window).await);
    }
    for (i, (what, rounds)) in SCENARIOS.iter().zip(&results).enumerate() {
        if rounds.is_empty() {
            continue;
        }
        summary(what, rounds, figures, (i < FLOORS_FROM).then_some(1.0));
    }
    drop(plant);
    drop(mosquitto);
    pin(std::process::id(), &before);
}

/// Twin RTU lines of one kind (`line-a`/`line-b`: frames at once, `trickle-a`/`trickle-b`:
/// bytes at character pace): mbpoll polls one and the gateway the other, started together and
/// measured over the same window. The lines pace both clients (neither can take the CPU from
/// the other), and whatever else the machine does in that window weighs on both: alternating
/// windows gave ratios that moved ±50% between rounds. Rounds swap the twins.
struct RtuTwins<'a> {
    plant: &'a Plant,
    dir: &'a Path,
    kind: &'a str,
    broker: u16,
    /// The gateway reaches the broker over this Unix socket rather than loopback TCP.
    socket: Option<&'a Path>,
    /// The gateway sends each poll's readings at once (`mqtt.batch = "0s"`).
    unbatched: bool,
    cpu: usize,
}

impl RtuTwins<'_> {
    async fn measure(&self, per_device: bool, round: usize, window: Duration) -> (Sample, Sample) {
        let start = |endpoint: &Endpoint| {
            let name = format!(
                "{}-{round}-{}{}{}",
                self.kind,
                if per_device { "dev" } else { "ch" },
                if self.socket.is_some() { "-unix" } else { "" },
                if self.unbatched { "-unbatched" } else { "" }
            );
            let config = gateway_config(
                self.dir,
                &name,
                endpoint,
                RTU_UNITS,
                self.broker,
                per_device,
                "1ms",
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

    /// `start`s a client on one twin and mbpoll on the other; both measured in one window.
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
        let mut g = Running::start(start(&endpoint(&gw_bus)));
        let mut m = Running::start(mbpoll(&endpoint(&mb_bus), RTU_UNITS, self.cpu));
        tokio::time::sleep(Duration::from_secs(3)).await;
        g.begin(self.plant, &gw_bus);
        m.begin(self.plant, &mb_bus);
        tokio::time::sleep(window).await;
        (g.end(self.plant, &gw_bus), m.end(self.plant, &mb_bus))
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

/// Builds `examples/rtu_floor.rs` (release) and returns its path; `None` (said) if it cannot.
fn floor_binary() -> Option<std::path::PathBuf> {
    let cargo = std::env::var("CARGO").unwrap_or_else(|_| "cargo".into());
    let manifest = Path::new(env!("CARGO_MANIFEST_DIR"));
    let built = Command::new(cargo)
        .args(["build", "--release", "--quiet", "--example", "rtu_floor"])
        .current_dir(manifest)
        .status()
        .is_ok_and(|s| s.success());
    let target = std::env::var("CARGO_TARGET_DIR")
        .map_or_else(|_| manifest.join("target"), std::path::PathBuf::from);
    let path = target.join("release/examples/rtu_floor");
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

/// A client being measured: CPU and transactions at the window's start.
struct Running {
    child: Child,
    start: (Cpu, u64),
}

impl Running {
    fn start(child: Child) -> Running {
        Running {
            child,
            start: (Cpu::default(), 0),
        }
    }

    fn begin(&mut self, plant: &Plant, bus: &str) {
        self.start = (cpu_of(self.child.id()), reads(plant, bus));
    }

    /// The window's figures; stops the client (SIGTERM).
    fn end(mut self, plant: &Plant, bus: &str) -> Sample {
        let (c1, r1) = (cpu_of(self.child.id()), reads(plant, bus));
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
        }
    }
}

/// One round of the TCP comparisons (results 0..3).
#[allow(clippy::too_many_arguments)]
async fn tcp_rounds(
    plant: &Plant,
    dir: &Path,
    configs: &[std::path::PathBuf],
    tcp: &Endpoint,
    broker: u16,
    cpu: usize,
    tcp_window: Duration,
    results: &mut [Rounds],
) {
    let warmup = Duration::from_secs(3);
    let short = Duration::from_secs(1);
    let m = measure(
        mbpoll(tcp, TCP_UNITS, cpu),
        plant,
        "hall",
        short,
        tcp_window,
    )
    .await;
    for (i, config) in configs[..2].iter().enumerate() {
        let g = measure(gateway(config, cpu), plant, "hall", warmup, tcp_window).await;
        results[i].push((g, m));
    }
    // The gateway polling at the rate mbpoll managed: every transaction pays its own
    // wake-ups, as mbpoll's do.
    let rate = m.tx as f64 / tcp_window.as_secs_f64();
    let poll_ms = (f64::from(TCP_UNITS) * YL67_READS_A_POLL / rate.max(1.0) * 1000.0) as u64;
    let paced = gateway_config(
        dir,
        "tcp-paced",
        tcp,
        TCP_UNITS,
        broker,
        false,
        &format!("{poll_ms}ms"),
    );
    let g = measure(gateway(&paced, cpu), plant, "hall", warmup, tcp_window).await;
    results[2].push((g, m));
}

//! The line-speed benchmark: `cargo bench --bench line` (about three minutes).
//!
//! Puts the simulator behind a line emulator (bytes no faster than the baud rate, 10 bits a
//! character, a module turnaround) and prints each figure against its target as a ratio:
//! - saturated bus: achieved transactions/s against the theoretical maximum, 9600 and 115200
//!   baud, 16 modules a bus, 4 buses at once;
//! - one module silent: the others' poll rate against their target;
//! - CPU per transaction: the pipeline (decode, counter, JSON, hand-off) in-process, and the
//!   whole gateway process on loopback Modbus TCP with a zero-latency simulator;
//! - 1000 devices x 4 channels at 1 Hz publishing to a real Mosquitto: CPU share and peak RSS;
//! - side by side with mbpoll (a bare C Modbus client), all on one CPU: the gateway's CPU per
//!   transaction over mbpoll's, Modbus TCP and RTU at 9600 baud (`sidebyside`).
//!
//! - the status page: CPU per transaction with 50 clients polling `/api/v1/status` against
//!   none (`status`);
//! - M-Bus: 250 meters on one TCP segment read as fast as they answer, CPU a transaction and
//!   peak RSS beside the Modbus TCP figure (`mbus`);
//! - the Modbus server output: 10 clients reading as fast as answered, requests a second, CPU
//!   a request and the bus's poll rate against no client (`plc`).
//!
//! `cargo bench --bench line NAME` runs only the parts whose name contains NAME (saturated,
//! silent, cpu, mbpoll, command, outputs, thousand, status, mbus, plc).

#[path = "line/plc_server.rs"]
mod plc_server;
#[path = "line/sidebyside.rs"]
mod sidebyside;
#[path = "line/status_poll.rs"]
mod status_poll;

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant, SystemTime};

use pulsegate::bus::BusTask;
use pulsegate::config::Config;
use pulsegate::modbus::driver::Modbus;
use pulsegate::reading::Output;
use pulsegate::sim::{Plant, SimConfig};

const TURNAROUND_MS: f64 = 2.0;

fn free_port() -> u16 {
    std::net::TcpListener::bind("127.0.0.1:0")
        .unwrap()
        .local_addr()
        .unwrap()
        .port()
}

fn temp_dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pulsegate-bench-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    std::fs::create_dir_all(&d).unwrap();
    d
}

/// One line of the report.
struct Figure {
    what: String,
    value: String,
    target: String,
    ratio: f64,
    pass: bool,
}

fn report(figures: &[Figure]) {
    println!(
        "\n{:<58} {:>22} {:>26} {:>8}  ",
        "figure", "measured", "target", "ratio"
    );
    for f in figures {
        println!(
            "{:<58} {:>22} {:>26} {:>8.3}  {}",
            f.what,
            f.value,
            f.target,
            f.ratio,
            if f.pass { "ok" } else { "MISSED" }
        );
    }
}

/// Gateway config text for the buses of `plant`, every device polled every `poll`.
fn gateway_toml(
    plant: &Plant,
    sim: &SimConfig,
    baud: u32,
    poll: &str,
    state_dir: &Path,
    extra: &str,
) -> String {
    let serial = format!("baud = {baud}\ntimeout = \"100ms\"\n");
    pulsegate::sim::gateway::GatewayToml {
        id: "bench",
        state_dir,
        gateway: "stats_interval = \"1h\"\n",
        mqtt_host: "127.0.0.1",
        mqtt_port: None,
        mqtt: extra,
        serial: &serial,
        tcp: "timeout = \"100ms\"\n",
    }
    .render(plant, &sim.every_device(poll))
}

/// A plant of `buses` RTU buses behind line emulators, `units` YL67 modules each.
fn rtu_plant(buses: usize, units: u8, baud: u32, silent: Option<u8>) -> SimConfig {
    let mut t = String::new();
    for b in 0..buses {
        t += &format!(
            "[buses.bus{b}]\nline = {{ baud = {baud}, turnaround = \"{TURNAROUND_MS}ms\" }}\n"
        );
        for u in 1..=units {
            t += &format!(
                "[buses.bus{b}.devices.b{b}m{u}]\nunit = {u}\nmodel = \"yl67\"\nsilent = {}\nchannels.enc0 = {{ rate = 100.0 }}\n",
                silent == Some(u)
            );
        }
    }
    SimConfig::from_toml(&t).unwrap()
}

/// Runs the bus tasks of `config` in-process for `warmup + window`; returns the outputs of the
/// window and the transactions each bus made in it.
async fn run_buses(config: &Config, warmup: Duration, window: Duration) -> (Vec<Output>, u64) {
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel();
    let shutdown = tokio_util::sync::CancellationToken::new();
    let mut gateway = config.gateway.clone();
    gateway.stats_interval = warmup;
    let mut handles = Vec::new();
    let mut keep = Vec::new();
    let health = pulsegate::health::Health::default();
    for bus in &config.buses {
        let Some(line) = bus.link.line::<pulsegate::modbus::config::Line>() else {
            unreachable!("the bench's buses are Modbus buses");
        };
        let (ctx, crx) = tokio::sync::mpsc::unbounded_channel();
        keep.push(ctx);
        handles.push(tokio::spawn(
            BusTask::new(
                bus.clone(),
                &gateway,
                tx.clone(),
                crx,
                health.heart(pulsegate::health::Loop::Bus(bus.name.clone())),
            )
            .run(Modbus::for_bus(bus, line), shutdown.clone()),
        ));
    }
    drop(tx);
    let start = Instant::now();
    let mut outputs = Vec::new();
    let mut stats: BTreeMap<String, Vec<u64>> = BTreeMap::new();
    // Stats come every `warmup`: transactions are counted between the first two. Outputs are
    // kept from `warmup` to `warmup + window`.
    let end = start + (warmup * 2).max(warmup + window) + Duration::from_millis(200);
    while Instant::now() < end {
        let Ok(Some(out)) = tokio::time::timeout(Duration::from_millis(100), rx.recv()).await
        else {
            continue;
        };
        let since = start.elapsed();
        match &out {
            // What the MQTT task would say: nothing here is waiting for a broker.
            Output::Checkpoint(c) => c.answer(true),
            Output::BusStats { bus, stats: s } => stats
                .entry(bus.to_string())
                .or_default()
                .push(s.transactions),
            _ if since > warmup && since <= warmup + window => outputs.push(out),
            _ => {}
        }
    }
    shutdown.cancel();
    for h in handles {
        let _ = h.await;
    }
    let tx: u64 = stats
        .values()
        .filter(|v| v.len() >= 2)
        .map(|v| v[1] - v[0])
        .sum();
    (outputs, tx)
}

/// Theoretical transactions per second of an RTU line: request, answer of `regs` registers,
/// turnaround, and the silent interval before the next request.
fn theoretical_tps(baud: u32, regs: u32) -> f64 {
    let char_s = 10.0 / f64::from(baud);
    let t35 = if baud > 19200 { 0.00175 } else { 3.5 * char_s };
    let chars = f64::from(8 + 5 + 2 * regs);
    1.0 / (chars * char_s + TURNAROUND_MS / 1000.0 + t35)
}

async fn saturated(baud: u32, figures: &mut Vec<Figure>) {
    let buses: usize = std::env::var("BENCH_BUSES")
        .ok()
        .and_then(|v| v.parse().ok())
        .unwrap_or(4);
    let sim = rtu_plant(buses, 16, baud, None);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir(&format!("sat{baud}"));
    let text = gateway_toml(&plant, &sim, baud, "1ms", &dir, "");
    let config = Config::from_toml(&text, &dir.join("g.toml"), Some(Default::default())).unwrap();
    let window = Duration::from_secs(10);
    let (_, tx) = run_buses(&config, window, window).await;
    let achieved = tx as f64 / window.as_secs_f64() / buses as f64;
    // Every poll of a YL67 in quadrature mode reads 8 count and 8 frequency registers.
    let theory = theoretical_tps(baud, 8);
    let ratio = achieved / theory;
    figures.push(Figure {
        what: format!("saturated bus at {baud} baud, 16 modules x 4 buses (tx/s a bus)"),
        value: format!("{achieved:.1} of {theory:.1}"),
        target: ">= 97% of theory".into(),
        ratio,
        pass: ratio >= 0.97,
    });
}

async fn one_silent(figures: &mut Vec<Figure>) {
    let baud = 9600;
    let sim = rtu_plant(1, 16, baud, Some(16));
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("silent");
    // 15 live modules x 2 transactions fill ~80% of the line at this interval.
    let per_poll = 2.0 / theoretical_tps(baud, 8);
    let poll = per_poll * 15.0 / 0.8;
    let text = gateway_toml(
        &plant,
        &sim,
        baud,
        &format!("{}ms", (poll * 1000.0) as u64),
        &dir,
        "",
    );
    let config = Config::from_toml(&text, &dir.join("g.toml"), Some(Default::default())).unwrap();
    // From 3 s in: the silent module's first failures and backoff probes are in the window.
    let window = Duration::from_secs(60);
    let (outputs, _) = run_buses(&config, Duration::from_secs(3), window).await;
    let mut per_device: BTreeMap<String, Vec<SystemTime>> = BTreeMap::new();
    for o in &outputs {
        let readings: &[pulsegate::reading::Reading] = match o {
            Output::DeviceReadings { readings, .. } => readings,
            _ => &[],
        };
        for r in readings.iter().filter(|r| &*r.channel == "enc0") {
            per_device
                .entry(r.device.to_string())
                .or_default()
                .push(r.ts);
        }
    }
    // Each live module's poll rate over the window, from its first to its last reading.
    let rate = |ts: &[SystemTime]| match (ts.first(), ts.last()) {
        (Some(a), Some(b)) if ts.len() > 1 => {
            (ts.len() - 1) as f64 / b.duration_since(*a).unwrap().as_secs_f64()
        }
        _ => 0.0,
    };
    let worst = (1..=15)
        .map(|u| {
            rate(
                per_device
                    .get(&format!("b0m{u}"))
                    .map(Vec::as_slice)
                    .unwrap_or(&[]),
            ) * poll
        })
        .fold(f64::INFINITY, f64::min);
    let target = 1.0 / poll;
    figures.push(Figure {
        what: format!("one of 16 modules silent at 9600 baud, poll {:.2} s", poll),
        value: format!("worst {:.3} of {target:.3} polls/s", worst * target),
        target: ">= 95% of poll rate".into(),
        ratio: worst,
        pass: worst >= 0.95,
    });
}

/// CPU time of the pipeline stages for one transaction of 4 channels, in-process.
fn pipeline_cpu(figures: &mut Vec<Figure>) {
    use pulsegate::counter::{Counter, CounterSpec, Direction, Restart, Stamp};
    use pulsegate::decode::decode;
    use pulsegate::profile::{Profiles, ValueType};
    use pulsegate::reading::Reading;
    let profile = Profiles::builtin().get("yl67").unwrap();
    let channels = profile.channels(&[0, 0, 0, 0]).unwrap();
    let spec = CounterSpec {
        modulus: 1 << 32,
        direction: Direction::Both,
        max_rate_hz: 50_000.0,
        restart: Restart::FromZero,
    };
    let mut counters: Vec<Counter> = channels.iter().map(|_| Counter::new(spec)).collect();
    let (tx, mut rx) = tokio::sync::mpsc::unbounded_channel::<Reading>();
    let n = 200_000u64;
    let cpu0 = cpu_time_self();
    let t0 = Instant::now();
    for i in 0..n {
        let words: Vec<u16> = (0..8).map(|k| (i as u16).wrapping_add(k)).collect();
        for (c, (ch, counter)) in channels.iter().zip(counters.iter_mut()).enumerate() {
            let count = decode(&words[c * 2..], ValueType::I32, profile.word_order).as_i64();
            let ts = SystemTime::now();
            if let Some(update) = counter.update(count + i as i64, Stamp::at(i * 10)) {
                let r = Reading {
                    device: "d".into(),
                    channel: ch.name.as_str().into(),
                    ts,
                    count,
                    freq_hz: Some(1.0),
                    rpm: None,
                    update,
                    kind: ch.kind,
                    units: None,
                    after_seq: None,
                    meter: None,
                    measured: None,
                };
                let body = pulsegate::publish::payload::reading(&r);
                std::hint::black_box(body);
                let _ = tx.send(r);
            }
        }
        while rx.try_recv().is_ok() {}
    }
    let per = (cpu_time_self() - cpu0).as_secs_f64() / n as f64;
    let _ = t0;
    figures.push(Figure {
        what: "CPU a transaction: decode + counter + JSON + hand-off, 4 ch".into(),
        value: format!("{:.2} us", per * 1e6),
        target: "<= 10 us".into(),
        ratio: per / 10e-6,
        pass: per <= 10e-6,
    });
}

fn cpu_time_self() -> Duration {
    cpu_of("self")
}

/// utime + stime of a process from /proc.
fn cpu_of(pid: &str) -> Duration {
    let stat = std::fs::read_to_string(format!("/proc/{pid}/stat")).unwrap_or_default();
    let fields: Vec<&str> = stat
        .rsplit(')')
        .next()
        .unwrap_or("")
        .split_whitespace()
        .collect();
    let ticks: u64 = fields.get(11).and_then(|v| v.parse().ok()).unwrap_or(0)
        + fields.get(12).and_then(|v| v.parse().ok()).unwrap_or(0);
    Duration::from_secs_f64(ticks as f64 / 100.0)
}

fn peak_rss_kb(pid: u32) -> u64 {
    let status = std::fs::read_to_string(format!("/proc/{pid}/status")).unwrap_or_default();
    status
        .lines()
        .find(|l| l.starts_with("VmHWM:"))
        .and_then(|l| l.split_whitespace().nth(1))
        .and_then(|v| v.parse().ok())
        .unwrap_or(0)
}

struct Mosquitto(Child, u16);

impl Mosquitto {
    /// Its Unix socket listener (in the temp dir: Mosquitto started as root binds it as user
    /// `mosquitto`, which may write there).
    fn socket_for(port: u16) -> PathBuf {
        std::env::temp_dir().join(format!("pulsegate-bench-mosquitto-{port}.sock"))
    }

    fn socket(&self) -> PathBuf {
        Mosquitto::socket_for(self.1)
    }

    fn start() -> Mosquitto {
        let port = free_port();
        let _ = std::fs::remove_file(Mosquitto::socket_for(port));
        let conf = std::env::temp_dir().join(format!("pulsegate-bench-mosquitto-{port}.conf"));
        std::fs::write(
            &conf,
            format!(
                "listener {port} 127.0.0.1\nlistener 0 {}\nallow_anonymous true\npersistence false\n",
                Mosquitto::socket_for(port).display()
            ),
        )
        .unwrap();
        let child = Command::new("/usr/sbin/mosquitto")
            .arg("-c")
            .arg(&conf)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("mosquitto (install it: scripts/test does)");
        let deadline = Instant::now() + Duration::from_secs(5);
        while std::net::TcpStream::connect(("127.0.0.1", port)).is_err()
            && Instant::now() < deadline
        {
            std::thread::sleep(Duration::from_millis(20));
        }
        Mosquitto(child, port)
    }
}

impl Drop for Mosquitto {
    fn drop(&mut self) {
        let _ = self.0.kill();
        let _ = self.0.wait();
        let _ = std::fs::remove_file(self.socket());
    }
}

/// A TCP plant of `buses` listeners with `units` YL67 modules each.
fn tcp_plant(buses: usize, units: u8) -> SimConfig {
    let mut t = String::new();
    for b in 0..buses {
        t += &format!("[buses.hall{b}]\nlisten = \"127.0.0.1:0\"\n");
        for u in 1..=units {
            t += &format!(
                "[buses.hall{b}.devices.h{b}m{u}]\nunit = {u}\nmodel = \"yl67\"\nchannels.enc0 = {{ rate = 100.0 }}\n"
            );
        }
    }
    SimConfig::from_toml(&t).unwrap()
}

/// The gateway binary on `config`, measured for `window` after `warmup`: CPU seconds used,
/// wall seconds, peak RSS in kB, and readings published (seen by counting at the broker).
async fn measure_gateway(config: &Path, warmup: Duration, window: Duration) -> (f64, f64, u64) {
    // PULSEGATE_BIN measures another build of the gateway (a profiling build, say).
    let bin = std::env::var("PULSEGATE_BIN")
        .unwrap_or_else(|_| env!("CARGO_BIN_EXE_pulsegate").to_string());
    let mut child = Command::new(bin)
        .args(["run", "--config"])
        .arg(config)
        .env("RUST_LOG", "warn")
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .unwrap();
    let pid = child.id();
    tokio::time::sleep(warmup).await;
    let (c0, t0) = (cpu_of(&pid.to_string()), Instant::now());
    tokio::time::sleep(window).await;
    let (c1, wall) = (cpu_of(&pid.to_string()), t0.elapsed());
    let rss = peak_rss_kb(pid);
    let _ = Command::new("kill")
        .args(["-TERM", &pid.to_string()])
        .status();
    let _ = child.wait();
    ((c1 - c0).as_secs_f64(), wall.as_secs_f64(), rss)
}

/// Counts Modbus transactions by reading the simulator's served requests is not possible from
/// outside, so the gateway's own stats give them: this runs it with stats every `window`.
async fn process_cpu_per_tx(figures: &mut Vec<Figure>) {
    let mosquitto = Mosquitto::start();
    let sim = tcp_plant(1, 50);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("cpu");
    let window = Duration::from_secs(10);
    let text = gateway_toml(
        &plant,
        &sim,
        9600,
        "1ms",
        &dir,
        &format!("port = {}", mosquitto.1),
    )
    .replace("stats_interval = \"1h\"", "stats_interval = \"5s\"");
    let path = dir.join("g.toml");
    std::fs::write(&path, text).unwrap();
    // Count transactions from the published stats.
    let stats_topic = "pulsegate/bench/bus/hall0/stats";
    let counts = subscribe_count(mosquitto.1, stats_topic);
    let (cpu, _wall, _) = measure_gateway(&path, Duration::from_secs(5), window).await;
    let tx = counts.transactions_in(window);
    let per = cpu / tx.max(1) as f64;
    figures.push(Figure {
        what: "CPU a transaction, whole process (Modbus TCP + MQTT I/O)".into(),
        value: format!("{:.1} us ({tx} tx)", per * 1e6),
        target: "(context for the above)".into(),
        ratio: per / 10e-6,
        pass: true,
    });
    drop(plant);
}

/// CPU a transaction with JSON alone against JSON and Sparkplug B on two connections (two
/// brokers), alternated in one window, three rounds each: the second output may cost less than
/// half again the first.
async fn two_outputs_cpu(figures: &mut Vec<Figure>) {
    let (local, scada) = (Mosquitto::start(), Mosquitto::start());
    let sim = tcp_plant(1, 50);
    let plant = Plant::start(&sim).await.unwrap();
    let two = format!(
        "[outputs.json]\nkind = \"json\"\n[outputs.scada]\nkind = \"sparkplug\"\nport = {}\n\
         [sparkplug]\ngroup_id = \"bench\"\n",
        scada.1
    );
    let (mut alone, mut both) = (Vec::new(), Vec::new());
    for round in 0..3 {
        for (outputs, into) in [("", &mut alone), (two.as_str(), &mut both)] {
            let dir = temp_dir(&format!("outputs-{round}-{}", into.len()));
            let text = gateway_toml(
                &plant,
                &sim,
                9600,
                "1ms",
                &dir,
                &format!("port = {}", local.1),
            )
            .replace("stats_interval = \"1h\"", "stats_interval = \"5s\"")
                + outputs;
            let path = dir.join("g.toml");
            std::fs::write(&path, text).unwrap();
            let counts = subscribe_count(local.1, "pulsegate/bench/bus/hall0/stats");
            let window = Duration::from_secs(10);
            let (cpu, _, _) = measure_gateway(&path, Duration::from_secs(5), window).await;
            let tx = counts.transactions_in(window).max(1);
            into.push(cpu / tx as f64);
        }
    }
    let median = |v: &mut Vec<f64>| {
        v.sort_by(f64::total_cmp);
        v[v.len() / 2]
    };
    let (a, b) = (median(&mut alone), median(&mut both));
    figures.push(Figure {
        what: "CPU a transaction, JSON alone (median of 3)".into(),
        value: format!("{:.1} us", a * 1e6),
        target: "(the anchor of the next)".into(),
        ratio: 1.0,
        pass: true,
    });
    figures.push(Figure {
        what: "CPU a transaction, JSON + Sparkplug, 2 connections".into(),
        value: format!("{:.1} us", b * 1e6),
        target: "< 1.5x JSON alone".into(),
        ratio: b / a,
        pass: b / a < 1.5,
    });
    drop(plant);
}

/// Stats messages seen on a topic, via mosquitto_sub (killed with the tap).
struct StatsTap(std::sync::Arc<std::sync::Mutex<Vec<(Instant, u64)>>>, u32);

impl Drop for StatsTap {
    fn drop(&mut self) {
        let _ = Command::new("kill").arg(self.1.to_string()).status();
    }
}

impl StatsTap {
    fn transactions_in(&self, window: Duration) -> u64 {
        let v = self.0.lock().unwrap();
        // Cumulative counts: the difference across the measured window.
        match (v.first(), v.last()) {
            (Some(a), Some(b)) if b.0 > a.0 => {
                ((b.1 - a.1) as f64 * window.as_secs_f64() / (b.0 - a.0).as_secs_f64()) as u64
            }
            _ => 0,
        }
    }
}

fn subscribe_count(port: u16, topic: &str) -> StatsTap {
    let store = std::sync::Arc::new(std::sync::Mutex::new(Vec::new()));
    let sink = store.clone();
    let mut child = Command::new("mosquitto_sub")
        .args(["-h", "127.0.0.1", "-p", &port.to_string(), "-t", topic])
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("mosquitto_sub (package mosquitto-clients)");
    let out = child.stdout.take().unwrap();
    let pid = child.id();
    std::thread::spawn(move || {
        use std::io::BufRead;
        for line in std::io::BufReader::new(out).lines().map_while(Result::ok) {
            if let Ok(v) = serde_json::from_str::<serde_json::Value>(&line)
                && let Some(tx) = v["transactions"].as_u64()
            {
                sink.lock().unwrap().push((Instant::now(), tx));
            }
        }
        let _ = child.wait();
    });
    StatsTap(store, pid)
}

/// An M-Bus segment on TCP with `meters` meters at primary addresses 1.. (an energy register,
/// power and flow temperature each, as a heat meter answers).
fn mbus_plant(meters: u8) -> SimConfig {
    let mut t = String::from("[mbus.field]\nlisten = \"127.0.0.1:0\"\n");
    for a in 1..=meters {
        t += &format!(
            "[mbus.field.meters.m{a}]\nid = {}\naddress = {a}\nmedium = 4\n\
             registers = [{{ quantity = \"energy_wh\", start = 1000, rate = 10.0 }}]\n\
             gauges = {{ power_w = 2300, flow_temperature_centi = 6025 }}\n",
            10_000_000 + u32::from(a)
        );
    }
    SimConfig::from_toml(&t).unwrap()
}

/// CPU a transaction of the whole gateway process reading 250 M-Bus meters on one TCP segment
/// as fast as they answer (one `REQ_UD2` a poll, three channels a meter), and its peak RSS:
/// beside the Modbus TCP figure of `cpu`, measured the same way.
async fn mbus_cpu(figures: &mut Vec<Figure>) {
    let mosquitto = Mosquitto::start();
    let sim = mbus_plant(250);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("mbus");
    let t = pulsegate::sim::gateway::GatewayToml {
        id: "bench",
        state_dir: &dir,
        gateway: "stats_interval = \"5s\"\n",
        mqtt_host: "127.0.0.1",
        mqtt_port: Some(mosquitto.1),
        mqtt: "",
        serial: "",
        tcp: "",
    };
    let meters = sim.every_meter("1ms");
    let text = t.render(&plant, &[]) + &t.meters(&plant, &meters, "timeout = \"100ms\"\n");
    let path = dir.join("g.toml");
    std::fs::write(&path, text).unwrap();
    let counts = subscribe_count(mosquitto.1, "pulsegate/bench/bus/field/stats");
    let window = Duration::from_secs(10);
    let (cpu, _wall, rss) = measure_gateway(&path, Duration::from_secs(5), window).await;
    let tx = counts.transactions_in(window);
    let per = cpu / tx.max(1) as f64;
    figures.push(Figure {
        what: "CPU a transaction, whole process, 250 M-Bus meters on TCP".into(),
        value: format!("{:.1} us ({tx} tx)", per * 1e6),
        target: "(beside the Modbus TCP figure)".into(),
        ratio: per / 10e-6,
        pass: true,
    });
    figures.push(Figure {
        what: "250 M-Bus meters on TCP, as fast as answered: peak RSS".into(),
        value: format!("{:.1} MB", rss as f64 / 1024.0),
        target: "< 30 MB".into(),
        ratio: rss as f64 / 1024.0 / 30.0,
        pass: (rss as f64 / 1024.0) < 30.0,
    });
    drop(plant);
}

async fn thousand_devices(figures: &mut Vec<Figure>) {
    let mosquitto = Mosquitto::start();
    let sim = tcp_plant(10, 100);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("k");
    let text = gateway_toml(
        &plant,
        &sim,
        9600,
        "1s",
        &dir,
        &format!("port = {}", mosquitto.1),
    );
    let path = dir.join("g.toml");
    std::fs::write(&path, text).unwrap();
    let (cpu, wall, rss) =
        measure_gateway(&path, Duration::from_secs(10), Duration::from_secs(30)).await;
    let share = cpu / wall;
    figures.push(Figure {
        what: "1000 devices x 4 channels at 1 Hz to Mosquitto: CPU".into(),
        value: format!("{:.1}% of a core", share * 100.0),
        target: "< 5% of one core".into(),
        ratio: share / 0.05,
        pass: share < 0.05,
    });
    let mb = rss as f64 / 1024.0;
    figures.push(Figure {
        what: "1000 devices x 4 channels at 1 Hz to Mosquitto: peak RSS".into(),
        value: format!("{mb:.1} MB"),
        target: "< 30 MB".into(),
        ratio: mb / 30.0,
        pass: mb < 30.0,
    });
    drop(plant);
}

/// MQTT receipt to module write, for presets sent while the bus is saturated at 9600 baud: the
/// time from publishing the command to the simulated module receiving the write.
async fn command_latency(figures: &mut Vec<Figure>) {
    let mosquitto = Mosquitto::start();
    let sim = rtu_plant(1, 16, 9600, None);
    let plant = Plant::start(&sim).await.unwrap();
    let dir = temp_dir("cmd");
    let text = gateway_toml(
        &plant,
        &sim,
        9600,
        "1ms",
        &dir,
        &format!("port = {}", mosquitto.1),
    );
    let config = Config::from_toml(&text, &dir.join("g.toml"), Some(Default::default())).unwrap();
    let shutdown = tokio_util::sync::CancellationToken::new();
    let gateway = tokio::spawn(pulsegate::app::run(config, shutdown.clone()));
    let mut options = rumqttc::v5::MqttOptions::new("bench-cmd", "127.0.0.1", mosquitto.1);
    options.set_keep_alive(Duration::from_secs(30));
    let (client, mut eventloop) = rumqttc::v5::AsyncClient::new(options, 10);
    tokio::spawn(async move { while eventloop.poll().await.is_ok() {} });
    tokio::time::sleep(Duration::from_secs(5)).await;
    let mut latencies = Vec::new();
    for i in 0..20u64 {
        let unit = (i % 15 + 1) as u8;
        plant
            .with_module("bus0", unit, |m, _| m.last_write = None)
            .unwrap();
        let sent = plant.now();
        let topic = format!("pulsegate/bench/b0m{unit}/enc0/cmd");
        let body = format!("{{\"op\":\"preset\",\"value\":{i}}}");
        client
            .publish(topic, rumqttc::v5::mqttbytes::QoS::AtLeastOnce, false, body)
            .await
            .unwrap();
        let deadline = Instant::now() + Duration::from_secs(3);
        while Instant::now() < deadline {
            if let Some(at) = plant
                .with_module("bus0", unit, |m, _| m.last_write)
                .unwrap()
            {
                latencies.push(at - sent);
                break;
            }
            tokio::time::sleep(Duration::from_millis(1)).await;
        }
        tokio::time::sleep(Duration::from_millis(137)).await;
    }
    shutdown.cancel();
    let _ = gateway.await;
    latencies.sort_by(f64::total_cmp);
    let pct = |p: f64| {
        latencies
            .get(((latencies.len() as f64 - 1.0) * p).round() as usize)
            .copied()
            .unwrap_or(f64::NAN)
            * 1000.0
    };
    // One poll transaction in flight (~36 ms), the read that books the count before the write
    // (~36 ms), and the write request itself (~11 ms) bound it from above.
    let bound = 3.0 / theoretical_tps(9600, 8) * 1000.0;
    figures.push(Figure {
        what: format!(
            "command latency, MQTT to module write, busy 9600 bus ({} cmds)",
            latencies.len()
        ),
        value: format!("p50 {:.0} ms, max {:.0} ms", pct(0.5), pct(1.0)),
        target: format!("< {bound:.0} ms (3 transactions)"),
        ratio: pct(1.0) / bound,
        pass: latencies.len() == 20 && pct(1.0) < bound,
    });
}

fn main() {
    let only = std::env::args().nth(1).filter(|a| !a.starts_with('-'));
    let rt = tokio::runtime::Builder::new_multi_thread()
        .enable_all()
        .build()
        .unwrap();
    let started = Instant::now();
    let mut figures = Vec::new();
    rt.block_on(async {
        let want = |name: &str| only.as_deref().is_none_or(|o| name.contains(o));
        if want("saturated") {
            saturated(9600, &mut figures).await;
            saturated(115200, &mut figures).await;
        }
        if want("silent") {
            one_silent(&mut figures).await;
        }
        if want("cpu") {
            pipeline_cpu(&mut figures);
            process_cpu_per_tx(&mut figures).await;
        }
        if want("mbus") {
            if !want("cpu") {
                process_cpu_per_tx(&mut figures).await;
            }
            mbus_cpu(&mut figures).await;
        }
        if want("mbpoll") {
            sidebyside::run(&mut figures).await;
        }
        if want("command") {
            command_latency(&mut figures).await;
        }
        if want("outputs") {
            two_outputs_cpu(&mut figures).await;
        }
        if want("thousand") {
            thousand_devices(&mut figures).await;
        }
        if want("status") {
            status_poll::run(&mut figures).await;
        }
        if want("plc") {
            plc_server::run(&mut figures).await;
        }
    });
    report(&figures);
    println!("\nbenchmark took {:.0} s", started.elapsed().as_secs_f64());
}

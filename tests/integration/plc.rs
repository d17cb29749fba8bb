//! The Modbus server output against real Modbus clients: tokio-modbus here, pymodbus
//! (tests/plc_clients.py) and mbpoll (libmodbus) from other projects, a real Mosquitto for the
//! MQTT totals they are compared with, the simulator on pseudo-terminals for the modules. The
//! writes are in `plc_commands`, the hostile clients in `plc_hostile`, the map's stability in
//! `plc_map`; the rig and the clients are here.

use std::io::{BufRead, BufReader, Write};
use std::net::SocketAddr;
use std::path::Path;
use std::process::{Child, ChildStdin, ChildStdout, Command, Stdio};
use std::time::{Duration, Instant};

use pulsegate::sim::Plant;
use serde_json::{Value, json};
use tokio_modbus::client::Reader as _;

use crate::support::*;

/// One YL67 counting on `a0` at 200 Hz, with a still `a1`.
pub(crate) const ONE: &str = "[buses.line1.devices.m]\nunit = 3\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0, rate = 200.0 }\nchannels.a1 = { count = 777 }\n";

/// The `[outputs]` of a gateway with JSON on MQTT and a Modbus server on `port`.
pub(crate) fn server_toml(port: u16, extra: &str) -> String {
    format!(
        "[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\nlisten = \"127.0.0.1:{port}\"\n{extra}"
    )
}

/// The i64 of four registers, high word first.
pub(crate) fn i64_of(w: &[u16]) -> i64 {
    w.iter().fold(0i64, |acc, x| (acc << 16) | i64::from(*x))
}

/// A device line of [`gateway_toml`].
pub(crate) type DeviceLine = (&'static str, &'static str, u8, &'static str, &'static str);

/// The YL67 of [`ONE`], polled every 100 ms.
pub(crate) const M: [DeviceLine; 1] = [("line1", "m", 3, "yl67", "100ms")];

/// What a [`Rig`] starts.
pub(crate) struct Setup<'a> {
    /// The simulator's plant.
    pub plant: &'a str,
    pub devices: &'a [DeviceLine],
    /// Extra keys of the Modbus output's table.
    pub server: &'a str,
    /// More gateway config (`[metrics]`, …).
    pub extra: &'a str,
    /// A file to write into the state directory first, and its text.
    pub state: Option<(&'static str, String)>,
    /// A command the gateway runs under (see [`Gateway::start_under`]).
    pub wrapper: &'a [&'a str],
}

impl Default for Setup<'_> {
    fn default() -> Self {
        Setup {
            plant: ONE,
            devices: &M,
            server: "",
            extra: "",
            state: None,
            wrapper: &[],
        }
    }
}

/// A gateway with a Modbus server output, its plant and broker, and a subscriber to all it
/// publishes.
pub(crate) struct Rig {
    pub plant: Plant,
    pub sub: Subscriber,
    pub gw: Gateway,
    pub config: std::path::PathBuf,
    /// The Modbus server's port on 127.0.0.1.
    pub port: u16,
    pub map: Vec<Value>,
    _broker: Broker,
}

impl Rig {
    /// Starts everything and waits until every device is online.
    pub async fn start(name: &str, setup: Setup<'_>) -> Rig {
        let broker = Broker::start();
        let plant = plant(setup.plant).await;
        let dir = temp_dir(name);
        if let Some((file, text)) = &setup.state {
            std::fs::write(dir.join(file), text).unwrap();
        }
        let port = free_port();
        // Every poll's readings go to the broker at once: the totals seen on MQTT are then
        // those the image had a moment before.
        let outputs = server_toml(port, setup.server) + setup.extra;
        let text = gateway_toml(&plant, broker.port, &dir, setup.devices, &outputs)
            .replace("[mqtt]\n", "[mqtt]\nbatch = \"0s\"\n");
        let config = write_config(&dir, &text);
        let sub = Subscriber::start(broker.port, "pulsegate/test/#").await;
        let gw = Gateway::start_under(&config, setup.wrapper);
        for (_, device, ..) in setup.devices {
            let t = format!("pulsegate/test/{device}/status");
            assert!(
                sub.wait_for(&t, Duration::from_secs(10), |m| m.payload == "online")
                    .await
                    .is_some(),
                "{device} online:\n{}",
                gw.log_text()
            );
        }
        let map = register_map(&config);
        Rig {
            plant,
            sub,
            gw,
            config,
            port,
            map,
            _broker: broker,
        }
    }

    pub fn addr(&self) -> SocketAddr {
        SocketAddr::from(([127, 0, 0, 1], self.port))
    }

    /// The published totals of a channel, in arrival order.
    pub fn totals(&self, device: &str, channel: &str) -> Vec<i64> {
        readings(&self.sub, &format!("pulsegate/test/{device}/{channel}"))
            .iter()
            .filter_map(|r| r["total"].as_i64())
            .collect()
    }

    /// The last total published for a channel (after waiting for its first: a device is
    /// online before its first reading is out).
    pub async fn last_total(&self, device: &str, channel: &str) -> i64 {
        let topic = format!("pulsegate/test/{device}/{channel}");
        let first = self.sub.wait_for(&topic, Duration::from_secs(10), |m| {
            m.json()["total"].is_i64()
        });
        assert!(first.await.is_some(), "a published total on {topic}");
        *self
            .totals(device, channel)
            .last()
            .expect("a published total")
    }

    /// The input-register address of a field, from `check --register-map --json`.
    pub fn address(&self, device: &str, channel: Option<&str>, field: &str) -> u16 {
        address_in(&self.map, device, channel, field)
    }

    /// Waits until a channel's published total is at least `total`.
    pub async fn published_up_to(&self, device: &str, channel: &str, total: i64) {
        let topic = format!("pulsegate/test/{device}/{channel}");
        let got = self
            .sub
            .wait_for(&topic, Duration::from_secs(20), |m| {
                m.json()["total"].as_i64().is_some_and(|t| t >= total)
            })
            .await;
        assert!(got.is_some(), "no total up to {total} on {topic}");
    }
}

/// `pulsegate check --config F --register-map --json`, parsed.
pub(crate) fn register_map(config: &Path) -> Vec<Value> {
    let out = Command::new(bin())
        .args(["check", "--config"])
        .arg(config)
        .args(["--register-map", "--json"])
        .output()
        .unwrap();
    assert!(
        out.status.success(),
        "check: {}",
        String::from_utf8_lossy(&out.stderr)
    );
    serde_json::from_slice::<Value>(&out.stdout)
        .expect("the map as JSON")
        .as_array()
        .expect("a list")
        .clone()
}

/// The input-register address of a field in a printed map.
pub(crate) fn address_in(map: &[Value], device: &str, channel: Option<&str>, field: &str) -> u16 {
    let channel = channel.map_or(Value::Null, |c| json!(c));
    let entry = map
        .iter()
        .find(|e| {
            e["device"] == device
                && e["channel"] == channel
                && e["field"] == field
                && e["table"] == "input"
        })
        .unwrap_or_else(|| panic!("{device} {channel} {field} is not in the map"));
    entry["address"].as_u64().unwrap() as u16
}

/// A PLC on pymodbus: tests/plc_clients.py on one connection, a JSON line per request.
pub(crate) struct Pymodbus {
    child: Child,
    stdin: ChildStdin,
    out: BufReader<ChildStdout>,
}

impl Pymodbus {
    /// Connects to the server on `port`, from `source` (a loopback address) when given.
    pub fn connect(port: u16, source: Option<&str>) -> Pymodbus {
        let script = concat!(env!("CARGO_MANIFEST_DIR"), "/tests/plc_clients.py");
        let mut child = Command::new("python3")
            .arg(script)
            .arg(port.to_string())
            .args(source)
            .stdin(Stdio::piped())
            .stdout(Stdio::piped())
            .spawn()
            .expect("python3 runs tests/plc_clients.py (scripts/test installs pymodbus)");
        let stdin = child.stdin.take().unwrap();
        let out = BufReader::new(child.stdout.take().unwrap());
        let mut client = Pymodbus { child, stdin, out };
        let hello = client.line();
        assert!(hello.get("connected").is_some(), "pymodbus: {hello}");
        client
    }

    fn line(&mut self) -> Value {
        let mut line = String::new();
        tokio::task::block_in_place(|| self.out.read_line(&mut line)).unwrap();
        serde_json::from_str(&line).unwrap_or_else(|_| panic!("pymodbus said {line:?}"))
    }

    /// One request (see tests/plc_clients.py), its answer.
    pub fn ask(&mut self, request: Value) -> Value {
        writeln!(self.stdin, "{request}").unwrap();
        self.line()
    }

    /// Input registers, or the answer that says why not.
    pub fn read(&mut self, unit: u8, address: u16, count: u16) -> Result<Vec<u16>, Value> {
        let a = self.ask(json!({"op": "read", "unit": unit, "address": address, "count": count}));
        match a["registers"].as_array() {
            Some(w) => Ok(w.iter().map(|x| x.as_u64().unwrap() as u16).collect()),
            None => Err(a),
        }
    }
}

impl Drop for Pymodbus {
    fn drop(&mut self) {
        let _ = self.child.kill();
        let _ = self.child.wait();
    }
}

/// mbpoll (libmodbus) reading `count` registers of `table` (3: input, 4: holding) from
/// `address` (0-based; mbpoll's references are 1-based), once.
pub(crate) fn mbpoll(
    port: u16,
    unit: u8,
    table: u8,
    address: u16,
    count: u16,
) -> Result<Vec<u16>, String> {
    let out = Command::new("mbpoll")
        .args(["-a", &unit.to_string(), "-t", &format!("{table}:hex")])
        .args(["-r", &(address + 1).to_string(), "-c", &count.to_string()])
        .args(["-1", "-q", "127.0.0.1", "-p", &port.to_string()])
        .output()
        .expect("mbpoll (scripts/test installs it)");
    let text = String::from_utf8_lossy(&out.stdout);
    if !out.status.success() {
        return Err(format!("{text}{}", String::from_utf8_lossy(&out.stderr)));
    }
    // "[41]: \t0x0000"
    Ok(text
        .lines()
        .filter(|l| l.starts_with('['))
        .filter_map(|l| l.split("0x").nth(1))
        .map(|h| u16::from_str_radix(h.trim(), 16).unwrap())
        .collect())
}

/// mbpoll writing `values` to holding registers from `address` (0-based).
pub(crate) fn mbpoll_write(
    port: u16,
    unit: u8,
    address: u16,
    values: &[i64],
) -> Result<(), String> {
    let out = Command::new("mbpoll")
        .args([
            "-a",
            &unit.to_string(),
            "-t",
            "4",
            "-r",
            &(address + 1).to_string(),
        ])
        .args(["-1", "-q", "127.0.0.1", "-p", &port.to_string()])
        .args(values.iter().map(i64::to_string))
        .output()
        .expect("mbpoll (scripts/test installs it)");
    match out.status.success() {
        true => Ok(()),
        false => Err(format!(
            "{}{}",
            String::from_utf8_lossy(&out.stdout),
            String::from_utf8_lossy(&out.stderr)
        )),
    }
}

/// 45 reads of a counting channel's total, taking turns between tokio-modbus, pymodbus and
/// mbpoll: each lies between the last total the subscriber had before the read was sent and
/// the first it got after the answer (every poll goes to the broker at once, `batch = "0s"`,
/// and the image has a reading before the broker does).
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn every_total_a_plc_reads_lies_between_the_mqtt_totals_published_around_it() {
    let rig = Rig::start("plc-around", Setup::default()).await;
    let total = rig.address("m", Some("a0"), "total");
    let mut ctx = tokio_modbus::client::tcp::connect_slave(rig.addr(), tokio_modbus::Slave(3))
        .await
        .unwrap();
    let mut py = Pymodbus::connect(rig.port, None);
    let mut checked = Vec::new();
    for i in 0..45 {
        let client = ["tokio-modbus", "pymodbus", "mbpoll"][i % 3];
        // The last total seen before the read was sent ...
        let before = rig.last_total("m", "a0").await;
        let read = match client {
            "tokio-modbus" => i64_of(&ctx.read_input_registers(total, 4).await.unwrap().unwrap()),
            "pymodbus" => i64_of(&py.read(3, total, 4).unwrap()),
            _ => i64_of(&mbpoll(rig.port, 3, 3, total, 4).unwrap()),
        };
        // ... and the first one seen after it was answered.
        let seen = rig.totals("m", "a0").len();
        let deadline = Instant::now() + Duration::from_secs(5);
        let after = loop {
            let totals = rig.totals("m", "a0");
            if let Some(t) = totals.get(seen) {
                break *t;
            }
            assert!(Instant::now() < deadline, "no total published after a read");
            tokio::time::sleep(Duration::from_millis(10)).await;
        };
        assert!(
            before <= read && read <= after,
            "{client}: {before} <= {read} <= {after}\n{}",
            rig.gw.log_text()
        );
        checked.push(read);
    }
    assert!(
        checked.first() < checked.last(),
        "the reads followed a moving total: {checked:?}"
    );
}

/// 2^48: a total counting across it changes three of its four registers at once.
const CARRY: i64 = 1 << 48;

/// The state file of a gateway whose `a0` on unit 3 of line1 stands at `total`, saved now.
fn state_at(total: i64) -> (&'static str, String) {
    let now_ms = std::time::SystemTime::now()
        .duration_since(std::time::UNIX_EPOCH)
        .unwrap()
        .as_millis() as u64;
    let text = json!({
        "version": 1,
        "channels": {
            "3/yl67/a0": {"count": 0, "at_ms": now_ms, "total": total, "seq": 1, "gap": false}
        },
        "holes": {},
        "clean": true
    });
    ("bus-line1.json", text.to_string())
}

/// A thousand fast reads (pymodbus, one connection, a read every millisecond or so) of a
/// counter at 5 kHz whose total crosses 2^48 meanwhile: each read is a total the gateway
/// published, none a mix of two (a torn read would be a total never published). The counter
/// stands still at 2^48 - 2500 (seeded in the state file) until the reads begin, so the carry
/// comes half a second into them however long the start took.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_thousand_fast_reads_of_a_5khz_counter_each_equal_a_published_total() {
    let plant_toml = "[buses.line1.devices.m]\nunit = 3\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\nchannels.a0 = { count = 0 }\n";
    let setup = Setup {
        plant: plant_toml,
        devices: &[("line1", "m", 3, "yl67", "20ms")],
        state: Some(state_at(CARRY - 2_500)),
        ..Setup::default()
    };
    let rig = Rig::start("plc-fast", setup).await;
    let total = rig.address("m", Some("a0"), "total");
    let mut py = Pymodbus::connect(rig.port, None);
    rig.published_up_to("m", "a0", CARRY - 2_500).await;
    assert_eq!(
        i64_of(&py.read(3, total, 4).unwrap()),
        CARRY - 2_500,
        "seeded"
    );
    let counting = rig
        .plant
        .with_module("line1", 3, |m, now| m.set_rate(now, "a0", 5000.0));
    assert_eq!(counting, Some(true), "a0 counts at 5 kHz from now");
    let answer =
        py.ask(json!({"op": "reads", "unit": 3, "address": total, "n": 1000, "pause": 0.001}));
    let reads: Vec<i64> = answer["totals"]
        .as_array()
        .unwrap_or_else(|| panic!("pymodbus: {answer}"))
        .iter()
        .map(|t| t.as_i64().unwrap())
        .collect();
    assert_eq!(reads.len(), 1000);
    let last = *reads.last().unwrap();
    rig.published_up_to("m", "a0", last).await;
    let published: std::collections::BTreeSet<i64> = rig.totals("m", "a0").into_iter().collect();
    let strays: Vec<&i64> = reads.iter().filter(|t| !published.contains(t)).collect();
    assert!(
        strays.is_empty(),
        "{} of 1000 reads are totals never published: {strays:?}",
        strays.len()
    );
    assert!(
        reads.windows(2).all(|w| w[0] <= w[1]),
        "reads never go back"
    );
    assert!(
        reads[0] < CARRY && CARRY <= last,
        "the reads span the carry into the 4th register: {} .. {last}",
        reads[0]
    );
    let distinct: std::collections::BTreeSet<&i64> = reads.iter().collect();
    assert!(
        distinct.len() >= 10,
        "the reads followed the polls ({} totals in {:.2} s)",
        distinct.len(),
        answer["seconds"]
    );
}

/// A module that stops answering: its unit's `online` reads 0 within 10 s, the other
/// module's stays 1.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_silenced_device_reads_offline_within_10_s() {
    let plant_toml =
        format!("{ONE}[buses.line1.devices.n]\nunit = 4\nmodel = \"yl67\"\nmodes = [1, 1, 1, 1]\n");
    let setup = Setup {
        plant: &plant_toml,
        devices: &[M[0], ("line1", "n", 4, "yl67", "100ms")],
        ..Setup::default()
    };
    let rig = Rig::start("plc-silent", setup).await;
    let mut py = Pymodbus::connect(rig.port, None);
    assert_eq!(py.read(4, 0, 1).unwrap(), [1], "n online before");
    rig.plant
        .with_module("line1", 4, |m, _| m.silent = true)
        .unwrap();
    let silenced = Instant::now();
    let head = loop {
        let head = py.read(4, 0, 3).unwrap();
        if head[0] == 0 || silenced.elapsed() > Duration::from_secs(10) {
            break head;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    };
    assert_eq!(
        head[0],
        0,
        "online of the silent unit after {:?}:\n{}",
        silenced.elapsed(),
        rig.gw.log_text()
    );
    let age = (u32::from(head[1]) << 16) | u32::from(head[2]);
    assert!(age < 60, "age: seconds since its last answer, {age}");
    assert_eq!(
        py.read(3, 0, 1).unwrap(),
        [1],
        "the other module stays online"
    );
    assert!(
        rig.sub
            .on("pulsegate/test/n/status")
            .iter()
            .any(|m| m.payload == "offline"),
        "MQTT says so too"
    );
}

#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn a_unit_id_no_device_answers_as_is_exception_0b() {
    let rig = Rig::start("plc-unit", Setup::default()).await;
    let unknown = tokio_modbus::client::tcp::connect_slave(rig.addr(), tokio_modbus::Slave(9))
        .await
        .unwrap()
        .read_input_registers(0, 1)
        .await
        .unwrap();
    assert_eq!(
        unknown,
        Err(tokio_modbus::ExceptionCode::GatewayTargetDevice)
    );
    let mut py = Pymodbus::connect(rig.port, None);
    assert_eq!(py.read(9, 0, 1).unwrap_err()["exception"], 11);
    // The same registers as holding registers (function 03).
    let total = rig.address("m", Some("a1"), "total");
    let holding = mbpoll(rig.port, 3, 4, total, 8).unwrap();
    let input = mbpoll(rig.port, 3, 3, total, 8).unwrap();
    assert_eq!(
        holding[..4],
        input[..4],
        "a still total reads the same both ways"
    );
}

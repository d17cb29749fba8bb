//! A toy third protocol, added the way a real one would be: S0 pulse inputs on the edge PC's
//! own GPIO chip (`protocol = "toy"`, a `chip` per bus, a `pin` per device). Everything it
//! knows is in this file (its config part, its line and address types, its driver) and it is
//! registered with one line ([`registry`]); nothing else in `src/` names it. The tests check a
//! config with it, print its plan, key its devices and run its bus through the registry on
//! tokio's paused clock, counting its pulses with the same core as every protocol.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc::{Receiver, unbounded_channel};
use tokio::task::JoinHandle;
use tokio_util::sync::CancellationToken;

use crate::bus::BusTask;
use crate::bus::device::{DeviceRt, PollError, ProtocolError};
use crate::bus::driver::{DeviceState, Driver, Executed, Preempt};
use crate::bus_health::WireCounters;
use crate::command::Request;
use crate::config::bus::{BusProtocol, Checking, LineOf, Protocol};
use crate::config::model::{Bus, BusParts, Device};
use crate::config::protocols::AddressOf;
use crate::config::walk::{Errors, Table};
use crate::config::{Address, Config, ConfigErrors, Known, Link};
use crate::profile::{ChannelKind, Profile};
use crate::protocols::{Entry, Registry};
use crate::reading::Output;
use crate::sample::{At, Channel, Counting, Direction, Sample, Wrap};
use crate::scan::ScanRequest;
use crate::state::BusState;

/// The gateway's protocols and the toy: its one line.
fn registry() -> Registry {
    Registry::standard().with(Entry {
        protocol: TOY,
        spawn,
    })
}

const TOY: Protocol = Protocol::of(&Gpio);

/// The toy protocol's config part.
struct Gpio;

/// A bus's GPIO chip.
#[derive(Debug, PartialEq)]
struct Chip(String);

/// A device's input pin.
#[derive(Debug, PartialEq, Eq)]
struct Pin(u8);

impl std::fmt::Display for Chip {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "GPIO {}", self.0)
    }
}

impl std::fmt::Display for Pin {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "pin {}", self.0)
    }
}

impl LineOf for Chip {
    fn protocol(&self) -> Protocol {
        TOY
    }
}

impl AddressOf for Pin {
    fn key(&self) -> String {
        self.0.to_string()
    }
    fn tag(&self) -> String {
        format!("p{}", self.0)
    }
    fn channels_from_device(&self) -> bool {
        true
    }
    fn writable_counts(&self) -> bool {
        false
    }
}

impl BusProtocol for Gpio {
    fn name(&self) -> &'static str {
        "toy"
    }

    fn title(&self) -> &'static str {
        "GPIO S0"
    }

    fn devices(&self) -> &'static str {
        "S0 inputs on the PC's own pins"
    }

    fn bus(&self, t: &mut Table<'_>, path: &str, _: &Checking<'_>, errs: &mut Errors) -> BusParts {
        let link = t.req::<String>("chip", errs).map(|c| Link::new(Chip(c)));
        let mut devices = Vec::new();
        for (name, value) in t.entries("devices", errs) {
            let path = format!("{path}.devices.{name}");
            let Some(mut d) = Table::of(value, &path, errs) else {
                continue;
            };
            let pin = d.int::<u8>("pin", errs);
            d.finish(errs);
            devices.extend(pin.map(|pin| input(&name, pin)));
        }
        BusParts {
            link,
            guard: Duration::ZERO,
            slow_poll: Duration::from_secs(60),
            devices,
        }
    }

    fn in_words(&self, bus: &Bus) -> String {
        let pins: Vec<String> = bus.devices.iter().map(|d| d.address.to_string()).collect();
        format!("bus {} ({}): {}\n", bus.name, bus.link, pins.join(", "))
    }
}

/// An S0 input read every second.
fn input(name: &str, pin: u8) -> Device {
    Device {
        name: name.to_string(),
        unit: pin,
        model: "s0".into(),
        profile: Arc::new(Profile::answered("s0", "S0 input", &[], Duration::ZERO)),
        poll: Duration::from_secs(1),
        timeout: None,
        commands: false,
        baud: None,
        channels: BTreeMap::new(),
        enabled: true,
        publish: Default::default(),
        payload: None,
        intervals: None,
        address: Address::new(Pin(pin)),
        server_unit: None,
    }
}

/// The toy's driver: each pin counts 5 pulses a poll.
struct Pulses;

/// What the toy keeps of a pin.
#[derive(Default)]
struct Input {
    declared: bool,
    count: i64,
}

/// The toy's one failure (it never happens: a pin always reads).
#[derive(Debug)]
struct Unread;

impl std::fmt::Display for Unread {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("pin not read")
    }
}

impl ProtocolError for Unread {
    fn device_answered(&self) -> bool {
        false
    }
}

impl DeviceState for Input {
    type Error = Unread;
}

const S0: Wrap = Wrap {
    bits: 32,
    direction: Direction::Up,
};

impl Driver for Pulses {
    type Device = Input;

    fn device(&self, _: &Bus, _: &Device, _: &BusState) -> Input {
        Input::default()
    }

    async fn poll(
        &mut self,
        d: &mut DeviceRt<Input>,
        _: Preempt<'_>,
    ) -> Result<Vec<Sample>, PollError<Unread>> {
        if !std::mem::replace(&mut d.proto.declared, true) {
            d.declare(vec![Channel {
                name: "pulses".into(),
                kind: ChannelKind::Counter,
                counting: Counting::Count {
                    wrap: S0,
                    max_rate_hz: 100.0,
                },
                units: None,
            }]);
        }
        d.proto.count += 5;
        Ok(vec![Sample::count(0, At::now(), d.proto.count, S0)])
    }

    async fn execute(&mut self, _: &mut DeviceRt<Input>, _: &Request) -> Executed {
        Executed::default()
    }

    fn wire(&self) -> (WireCounters, Duration) {
        (WireCounters::default(), Duration::ZERO)
    }

    fn is_line_fault(&self, _: &PollError<Unread>) -> bool {
        false
    }

    fn ready_for_commands(&self, _: &DeviceRt<Input>) -> bool {
        false
    }

    fn close(&mut self) {}
}

/// The toy's driver on a bus of its own.
fn spawn(
    task: BusTask,
    bus: &Bus,
    _: Receiver<ScanRequest>,
    shutdown: CancellationToken,
) -> Option<JoinHandle<()>> {
    bus.link.line::<Chip>()?;
    Some(tokio::spawn(task.run(Pulses, shutdown)))
}

const PLANT: &str = "[buses.pins]\nprotocol = \"toy\"\nchip = \"gpiochip0\"\n\
    [buses.pins.devices.door]\npin = 17\n[buses.pins.devices.gate]\npin = 4\n\
    [buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n";

fn check(registry: &Registry, name: &str, buses: &str) -> Result<Config, ConfigErrors> {
    let dir = std::env::temp_dir().join(format!("pulsegate-toy-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let text = format!("[gateway]\nid = \"t\"\nstate_dir = {dir:?}\n{buses}");
    let known = Known {
        kinds: crate::publish::formats::Registry::standard().kinds(),
        protocols: registry.protocols(),
    };
    Config::from_toml_with(&text, &dir.join("t.toml"), Some(HashMap::new()), &known)
}

#[test]
fn a_toy_protocol_registered_with_one_line_is_checked_keyed_and_said() {
    let config = check(&registry(), "checked", PLANT).expect("the toy's config");
    let pins = config.buses.iter().find(|b| b.name == "pins").unwrap();
    assert_eq!(pins.link.protocol(), TOY);
    assert_eq!(pins.link.line::<Chip>(), Some(&Chip("gpiochip0".into())));
    let door = pins.devices.iter().find(|d| d.name == "door").unwrap();
    assert_eq!(
        (door.place(), door.place_tag()),
        ("17".into(), "p17".into())
    );
    assert_eq!(door.address.of::<Pin>(), Some(&Pin(17)));
    assert!(door.channels_from_device() && !door.writable_counts());
    let plan = crate::report::poll_plan(&config);
    assert!(
        plan.contains("bus pins (GPIO gpiochip0): pin 17, pin 4"),
        "{plan}"
    );
    assert!(plan.contains("bus l (TCP 127.0.0.1:502)"), "{plan}");
}

#[test]
fn the_toy_reads_its_own_keys_and_names_what_is_wrong() {
    let broken =
        "[buses.pins]\nprotocol = \"toy\"\n[buses.pins.devices.door]\npin = 300\nunit = 1\n";
    let err = check(&registry(), "broken", broken)
        .unwrap_err()
        .to_string();
    assert!(err.contains("buses.pins.chip"), "{err}");
    assert!(err.contains("buses.pins.devices.door.pin"), "{err}");
    assert!(err.contains("buses.pins.devices.door.unit"), "{err}");
}

#[test]
fn a_protocol_left_out_of_the_registry_cannot_be_parsed_and_the_error_lists_the_registry() {
    let err = check(&Registry::standard(), "left-out", PLANT).unwrap_err();
    let err = err.to_string();
    assert!(
        err.contains("unknown protocol \"toy\": use \"modbus\" or \"mbus\""),
        "{err}"
    );
    let err = check(&registry(), "listed", "[buses.x]\nprotocol = \"dlms\"\n").unwrap_err();
    let err = err.to_string();
    assert!(
        err.contains("use \"modbus\" or \"mbus\" or \"toy\""),
        "{err}"
    );
    let twice = std::panic::catch_unwind(|| registry().with(crate::protocols::STANDARD[0]));
    assert!(twice.is_err(), "a protocol registered twice is refused");
}

#[tokio::test(start_paused = true)]
async fn the_toy_bus_runs_through_the_registry_and_the_core_counts_its_pulses() {
    let config = check(&registry(), "runs", PLANT).unwrap();
    let pins = config.buses.iter().find(|b| b.name == "pins").unwrap();
    let (out_tx, mut out) = unbounded_channel();
    let (_commands, rx) = unbounded_channel();
    let heart = crate::health::Health::default().heart(crate::health::Loop::Bus("pins".into()));
    let task = BusTask::new(pins.clone(), &config.gateway, out_tx, rx, heart);
    let (_scans, scan_rx) = tokio::sync::mpsc::channel(1);
    let stop = CancellationToken::new();
    let running = registry().spawn(task, pins, scan_rx, stop.clone());
    let mut totals: BTreeMap<(String, String), i64> = BTreeMap::new();
    let deadline = tokio::time::Instant::now() + Duration::from_secs(5);
    while let Ok(Some(o)) = tokio::time::timeout_at(deadline, out.recv()).await {
        match o {
            Output::Checkpoint(c) => c.answer(true),
            Output::DeviceReadings { readings, .. } => {
                for r in readings {
                    totals.insert(
                        (r.device.to_string(), r.channel.to_string()),
                        r.update.total,
                    );
                }
            }
            _ => {}
        }
    }
    stop.cancel();
    running.await.unwrap();
    let door = totals[&("door".to_string(), "pulses".to_string())];
    let gate = totals[&("gate".to_string(), "pulses".to_string())];
    // Polled every second for 5 s: 5 pulses a poll, the first read the counter's start.
    assert!((15..=25).contains(&door) && door % 5 == 0, "{totals:?}");
    assert_eq!(door, gate, "{totals:?}");
}

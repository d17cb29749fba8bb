//! The commissioning subcommands of `pulsegate` (clap) and their terminal output.

use std::io::{IsTerminal, Write as _};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use super::modbus::scan::ScanEvent;
use super::modbus::setup::Wanted;
use crate::command::Op;
use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::outcome::Found;
use crate::profile::Profiles;

/// How to reach the modules.
#[derive(clap::Args, Debug, Clone)]
pub struct LineArgs {
    /// Serial port of the RS-485 adapter, e.g. /dev/ttyUSB0.
    #[arg(long)]
    port: Option<PathBuf>,
    /// Modbus TCP instead: HOST[:PORT] (port 502 unless given; the ZH-YX1600 uses 20108).
    #[arg(long, conflicts_with = "port")]
    host: Option<String>,
    /// Serial parity: none | even | odd (default: none for Modbus, even for M-Bus).
    #[arg(long)]
    parity: Option<String>,
    /// Answer timeout before line time is added (default: the models' 100 ms).
    #[arg(long)]
    timeout: Option<humantime::Duration>,
}

/// One unit on the line: where, at what speed, which id.
#[derive(clap::Args, Debug, Clone)]
pub struct UnitArgs {
    #[command(flatten)]
    line: LineArgs,
    /// Baud rate to talk at (default: 9600 for Modbus, 2400 for M-Bus).
    #[arg(long)]
    baud: Option<u32>,
    /// Unit id of the module (Modbus).
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=247))]
    unit: Option<u8>,
}

impl UnitArgs {
    /// The Modbus unit, which every Modbus command needs.
    fn unit(&self) -> Result<u8, CommissionError> {
        self.unit
            .ok_or_else(|| CommissionError::BadInput("give --unit N (1-247) of the module".into()))
    }

    /// The Modbus baud rate.
    fn baud(&self) -> u32 {
        self.baud.unwrap_or(9600)
    }
}

/// The protocol a commissioning command speaks.
#[derive(clap::ValueEnum, Debug, Clone, Copy, PartialEq, Eq, Default)]
pub enum ProtocolArg {
    #[default]
    Modbus,
    Mbus,
}

/// One module on the line, of a known (or identified) model.
#[derive(clap::Args, Debug, Clone)]
pub struct ModuleArgs {
    #[command(flatten)]
    at: UnitArgs,
    /// Model name, or "auto" to identify it from its identification registers.
    #[arg(long, default_value = "auto")]
    model: String,
}

/// Commissioning commands: survey and set up a line before a config exists.
#[derive(clap::Subcommand, Debug)]
pub enum Commission {
    /// Find the units that answer on a line, their models and baud rates (M-Bus: the meters,
    /// their ids, manufacturers, versions, media and primary addresses).
    Scan {
        #[command(flatten)]
        line: LineArgs,
        /// modbus | mbus.
        #[arg(long, value_enum, default_value_t = ProtocolArg::Modbus)]
        protocol: ProtocolArg,
        /// M-Bus: the wildcard search by secondary address (finds meters that share a primary
        /// address, 0 as shipped), instead of asking primary addresses.
        #[arg(long)]
        secondary: bool,
        /// A baud rate, or "all": every rate the profiles support, fastest first (default 9600;
        /// M-Bus: 2400).
        #[arg(long)]
        baud: Option<String>,
        /// Unit ids to ask: "1-247", "5", "1,3,10-20" (M-Bus: primary addresses, default
        /// "0-250").
        #[arg(long)]
        units: Option<String>,
        /// Print a gateway config for what was found (the table goes to stderr).
        #[arg(long, conflicts_with = "json")]
        toml: bool,
        /// Print what was found as JSON.
        #[arg(long)]
        json: bool,
        /// Ask every identification register even when a unit is silent on the first (for
        /// modules that stay silent on registers they lack; doubles the time per empty unit).
        #[arg(long)]
        every_probe: bool,
    },
    /// Read one module's channels, decoded as the gateway publishes them (M-Bus: one meter's
    /// answer, every record with its value in its unit).
    Read {
        #[command(flatten)]
        module: ModuleArgs,
        /// modbus | mbus.
        #[arg(long, value_enum, default_value_t = ProtocolArg::Modbus)]
        protocol: ProtocolArg,
        /// M-Bus: the meter's primary address (0-250).
        #[arg(long, conflicts_with = "id")]
        address: Option<u8>,
        /// M-Bus: the meter's 8-digit id (its secondary address; F for any digit).
        #[arg(long)]
        id: Option<String>,
        /// Print JSON instead of a table.
        #[arg(long)]
        json: bool,
        /// Read again at this interval, in place, with deltas (until Ctrl-C).
        #[arg(long)]
        watch: Option<humantime::Duration>,
    },
    /// Clear one channel's count (written and read back as the MQTT command does).
    Clear {
        #[command(flatten)]
        module: ModuleArgs,
        #[arg(long)]
        channel: String,
    },
    /// Preset one channel's count (written and read back as the MQTT command does).
    Preset {
        #[command(flatten)]
        module: ModuleArgs,
        #[arg(long)]
        channel: String,
        #[arg(long, allow_negative_numbers = true)]
        value: i64,
    },
    /// Change settings the module's datasheet documents; confirmed, written, read back.
    Setup {
        #[command(flatten)]
        module: ModuleArgs,
        /// New unit id.
        #[arg(long)]
        new_unit: Option<String>,
        /// New baud rate.
        #[arg(long)]
        new_baud: Option<String>,
        /// ZH-YX1600: state of every counter after power-up: up | down | stopped.
        #[arg(long)]
        power_on: Option<String>,
        /// Pulses per revolution of a channel: CHANNEL=N (repeatable).
        #[arg(long, value_name = "CHANNEL=N")]
        ppr: Vec<String>,
        /// Any other documented setting: NAME=VALUE, e.g. parity=even (repeatable).
        #[arg(long, value_name = "NAME=VALUE")]
        set: Vec<String>,
        /// Write without asking.
        #[arg(long)]
        yes: bool,
    },
    /// Read or write raw holding registers (model unknown).
    Raw {
        #[command(flatten)]
        at: UnitArgs,
        #[command(subcommand)]
        op: RawOp,
    },
}

/// A raw register operation.
#[derive(clap::Subcommand, Debug)]
pub enum RawOp {
    /// Read COUNT registers from START (FC03).
    Read {
        #[arg(value_parser = super::modbus::raw::parse_u16)]
        start: u16,
        #[arg(value_parser = super::modbus::raw::parse_u16, default_value = "1")]
        count: u16,
    },
    /// Write VALUES from ADDRESS (one: FC06, more: FC16).
    Write {
        #[arg(value_parser = super::modbus::raw::parse_u16)]
        address: u16,
        #[arg(value_parser = super::modbus::raw::parse_u16, required = true)]
        values: Vec<u16>,
        /// Write without asking.
        #[arg(long)]
        yes: bool,
    },
}

/// Runs a commissioning command; prints errors and returns the exit status.
pub async fn run(command: Commission) -> ExitCode {
    match run_inner(command).await {
        Ok(()) => ExitCode::SUCCESS,
        Err(e) => {
            eprintln!("error: {e}");
            ExitCode::from(e.exit_code())
        }
    }
}

fn target(line: &LineArgs) -> Result<Target, CommissionError> {
    let parity = line.parity.as_deref().unwrap_or("none");
    Target::parse(line.port.clone(), line.host.clone(), parity)
}

/// The M-Bus segment of `line` at `baud` (default 2400, even parity).
fn segment(line: &LineArgs, baud: Option<u32>) -> Result<super::mbus::Segment, CommissionError> {
    let parity = line.parity.as_deref().unwrap_or("even");
    Ok(super::mbus::Segment {
        target: Target::parse(line.port.clone(), line.host.clone(), parity)?,
        baud: baud.unwrap_or(2400),
        timeout: line.timeout.map(Into::into),
    })
}

fn answer_time(line: &LineArgs, profiles: &Profiles) -> Duration {
    line.timeout
        .map(Into::into)
        .unwrap_or_else(|| crate::driver::modbus::probe::answer_time(profiles))
}

/// Cancelled at Ctrl-C.
fn ctrl_c() -> CancellationToken {
    let token = CancellationToken::new();
    let t = token.clone();
    tokio::spawn(async move {
        if tokio::signal::ctrl_c().await.is_ok() {
            t.cancel();
        }
    });
    token
}

async fn run_inner(command: Commission) -> Result<(), CommissionError> {
    let profiles = Profiles::builtin();
    match command {
        Commission::Scan {
            line,
            protocol,
            secondary,
            baud,
            units,
            toml,
            json,
            every_probe,
        } => {
            let how = ScanHow {
                toml,
                json,
                every_probe,
            };
            if protocol == ProtocolArg::Mbus {
                return scan_meters(&line, baud, units, secondary, how).await;
            }
            if secondary {
                return Err(CommissionError::BadInput(
                    "--secondary is M-Bus's search: give --protocol mbus".into(),
                ));
            }
            let baud = baud.unwrap_or_else(|| "9600".into());
            let units = units.unwrap_or_else(|| "1-247".into());
            scan(&line, &baud, &units, how, &profiles).await
        }
        Commission::Read {
            module,
            protocol: ProtocolArg::Mbus,
            address,
            id,
            json,
            ..
        } => read_meter(&module.at, address, id.as_deref(), json).await,
        Commission::Read {
            module,
            json,
            watch,
            ..
        } => read(&module, json, watch, &profiles).await,
        Commission::Clear { module, channel } => {
            write_count(&module, &channel, Op::Clear, &profiles).await
        }
        Commission::Preset {
            module,
            channel,
            value,
        } => write_count(&module, &channel, Op::Preset(value), &profiles).await,
        Commission::Setup {
            module,
            new_unit,
            new_baud,
            power_on,
            ppr,
            set,
            yes,
        } => {
            let wanted = wanted(new_unit, new_baud, power_on, &ppr, &set)?;
            setup(&module, &wanted, yes, &profiles).await
        }
        Commission::Raw { at, op } => raw(&at.line, at.baud(), at.unit()?, op, &profiles).await,
    }
}

/// `scan --protocol mbus`: primary addresses, or `--secondary` the wildcard search.
async fn scan_meters(
    line: &LineArgs,
    baud: Option<String>,
    units: Option<String>,
    secondary: bool,
    how: ScanHow,
) -> Result<(), CommissionError> {
    let baud = match baud.as_deref() {
        None => None,
        Some(b) => Some(b.parse::<u32>().map_err(|_| {
            CommissionError::BadInput(format!("--baud {b:?}: an M-Bus scan takes one rate"))
        })?),
    };
    let segment = segment(line, baud)?;
    let scan = super::mbus::MeterScan {
        secondary,
        addresses: super::mbus::parse_addresses(units.as_deref().unwrap_or("0-250"))?,
    };
    let cancel = ctrl_c();
    let tty = std::io::stderr().is_terminal();
    let progress = |text: &str| {
        if tty {
            eprint!("\r\x1b[K{text}");
        } else if text.starts_with("found") {
            eprintln!("{text}");
        }
    };
    let (found, collisions, problems) =
        super::mbus::scan(&segment, line.host.as_deref(), &scan, &cancel, progress).await?;
    if tty {
        eprint!("\r\x1b[K");
    }
    for p in &problems {
        eprintln!("  {p}");
    }
    if secondary {
        eprintln!("{collisions} collision(s) resolved digit by digit");
    }
    let table = super::mbus::found_table(&found);
    if how.toml {
        eprint!("{table}");
        print!("{}", super::mbus::config_snippet(&segment, &found));
    } else if how.json {
        let list: Vec<_> = found.iter().map(super::mbus::found_json).collect();
        let out = serde_json::json!({ "found": list, "collisions": collisions,
            "problems": problems, "interrupted": cancel.is_cancelled() });
        println!("{out}");
    } else {
        print!("{table}");
    }
    Ok(())
}

/// `read --protocol mbus`: one meter's answer.
async fn read_meter(
    at: &UnitArgs,
    address: Option<u8>,
    id: Option<&str>,
    json: bool,
) -> Result<(), CommissionError> {
    let segment = segment(&at.line, at.baud)?;
    let meter = super::mbus::meter_at(address, id)?;
    let (header, records) = super::mbus::read(&segment, at.line.host.as_deref(), meter).await?;
    let answer = super::mbus::answer_json(&header, &records);
    if json {
        println!("{answer}");
    } else {
        print!("{}", super::mbus::answer_table(&answer, &records));
    }
    Ok(())
}

/// Output and probing choices of a scan.
struct ScanHow {
    toml: bool,
    json: bool,
    every_probe: bool,
}

async fn scan(
    line: &LineArgs,
    baud: &str,
    units: &str,
    how: ScanHow,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let ScanHow {
        toml,
        json,
        every_probe,
    } = how;
    let target = target(line)?;
    let units =
        crate::driver::modbus::probe::parse_units(units).map_err(CommissionError::BadInput)?;
    let bauds = super::modbus::scan::scan_bauds(baud, profiles)?;
    target.check_free()?;
    let cancel = ctrl_c();
    let tty = std::io::stderr().is_terminal();
    let mut progress = |e: ScanEvent<'_>| progress(e, tty);
    let plan = super::modbus::scan::ScanPlan {
        bauds,
        units,
        answer: answer_time(line, profiles),
        every_probe,
    };
    let outcome =
        super::modbus::scan::scan_line(&target, &plan, profiles, &cancel, &mut progress).await?;
    if tty {
        eprint!("\r\x1b[K");
    }
    if outcome.interrupted {
        eprintln!("interrupted: what was found so far");
    }
    let table = found_table(&outcome.found);
    if toml {
        eprint!("{table}");
        print!(
            "{}",
            super::modbus::snippet::config_snippet(&target, &outcome.found)
        );
    } else if json {
        println!(
            "{}",
            serde_json::json!({ "found": outcome.found, "interrupted": outcome.interrupted })
        );
    } else {
        print!("{table}");
    }
    Ok(())
}

fn progress(e: ScanEvent<'_>, tty: bool) {
    match e {
        ScanEvent::Baud {
            baud,
            units,
            estimate,
        } => {
            let at = baud.map(|b| format!(" at {b} baud")).unwrap_or_default();
            eprintln!(
                "scanning {units} units{at} (about {:.0} s if none answers; Ctrl-C stops with what was found)",
                estimate.as_secs_f64()
            );
        }
        ScanEvent::Asking { unit, index, of } if tty => {
            eprint!("\r  unit {unit} ({}/{of})\x1b[K", index + 1);
            let _ = std::io::stderr().flush();
        }
        ScanEvent::Asking { .. } => {}
        ScanEvent::Found(f) => {
            if tty {
                eprint!("\r\x1b[K");
            }
            eprintln!(
                "  found unit {}: {}",
                f.unit,
                f.model.as_deref().unwrap_or("unknown model")
            );
        }
        ScanEvent::Garbled { baud, unit } => {
            if tty {
                eprint!("\r\x1b[K");
            }
            let at = baud.map(|b| format!(" at {b} baud")).unwrap_or_default();
            eprintln!("  unit {unit}{at}: garbled answer (another baud rate or parity?)");
        }
    }
}

fn found_table(found: &[Found]) -> String {
    let mut t = format!(
        "{:<7} {:>4}  {:<10} {:<14} channels\n",
        "baud", "unit", "model", "work modes"
    );
    for f in found {
        t += &format!(
            "{:<7} {:>4}  {:<10} {:<14} {}\n",
            f.baud
                .map(|b| b.to_string())
                .unwrap_or_else(|| "tcp".into()),
            f.unit,
            f.model.as_deref().unwrap_or("?"),
            format!("{:?}", f.modes),
            if f.channels.is_empty() {
                f.note.clone().unwrap_or_default()
            } else {
                f.channels.join(" ")
            }
        );
    }
    t += &format!("{} unit(s) found\n", found.len());
    t
}

async fn read(
    m: &ModuleArgs,
    json: bool,
    watch: Option<humantime::Duration>,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let target = target(&m.at.line)?;
    let (unit, baud) = (m.at.unit()?, m.at.baud());
    let mut link = target.open(baud)?;
    let profile =
        super::modbus::read::resolve_model(&mut link, &target, profiles, unit, &m.model, baud)
            .await?;
    let mut rt = super::modbus::read::poller(&target, baud, unit, &profile, &link);
    let Some(every) = watch.map(Duration::from) else {
        let value =
            super::modbus::read::read_once(&mut rt, &mut link, &profile, &target, baud).await?;
        if json {
            println!("{value}");
        } else {
            print!("{}", super::modbus::read::table(&value, None));
        }
        return Ok(());
    };
    let cancel = ctrl_c();
    let tty = std::io::stdout().is_terminal();
    let mut previous = None;
    while !cancel.is_cancelled() {
        let value =
            super::modbus::read::read_once(&mut rt, &mut link, &profile, &target, baud).await?;
        if json {
            println!("{value}");
        } else {
            if tty {
                print!("\x1b[H\x1b[J");
            }
            print!("{}", super::modbus::read::table(&value, previous.as_ref()));
        }
        let _ = std::io::stdout().flush();
        previous = Some(value);
        tokio::select! {
            () = tokio::time::sleep(every) => {}
            () = cancel.cancelled() => {}
        }
    }
    Ok(())
}

async fn write_count(
    m: &ModuleArgs,
    channel: &str,
    op: Op,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let target = target(&m.at.line)?;
    let (unit, baud) = (m.at.unit()?, m.at.baud());
    let mut link = target.open(baud)?;
    let profile =
        super::modbus::read::resolve_model(&mut link, &target, profiles, unit, &m.model, baud)
            .await?;
    if !profile.all_channels().iter().any(|c| c.name == channel) {
        return Err(CommissionError::BadInput(format!(
            "model {} has no channel {channel}",
            profile.model
        )));
    }
    let mut rt = super::modbus::read::poller(&target, baud, unit, &profile, &link);
    let got = super::modbus::read::write_count(&mut rt, &mut link, &target, channel, op).await?;
    let what = if matches!(op, Op::Clear) {
        "cleared"
    } else {
        "preset"
    };
    match got {
        Some(v) => println!("unit {} {channel}: {what}; reads back {v}", unit),
        None => println!("unit {} {channel}: {what}", unit),
    }
    Ok(())
}

/// The changes asked for on the command line, in the profiles' setting names.
fn wanted(
    new_unit: Option<String>,
    new_baud: Option<String>,
    power_on: Option<String>,
    ppr: &[String],
    set: &[String],
) -> Result<Vec<Wanted>, CommissionError> {
    let mut out = Vec::new();
    for (setting, value) in [
        ("unit", new_unit),
        ("baud", new_baud),
        ("power_on", power_on),
    ] {
        if let Some(value) = value {
            out.push(Wanted {
                setting: setting.into(),
                channel: None,
                value,
            });
        }
    }
    for p in ppr {
        let (channel, value) = p.split_once('=').ok_or_else(|| {
            CommissionError::BadInput(format!("--ppr {p:?}: give CHANNEL=N, e.g. enc0=360"))
        })?;
        out.push(Wanted {
            setting: "ppr".into(),
            channel: Some(channel.into()),
            value: value.into(),
        });
    }
    for s in set {
        let (name, value) = s.split_once('=').ok_or_else(|| {
            CommissionError::BadInput(format!("--set {s:?}: give NAME=VALUE, e.g. parity=even"))
        })?;
        out.push(Wanted {
            setting: name.into(),
            channel: None,
            value: value.into(),
        });
    }
    if out.is_empty() {
        return Err(CommissionError::BadInput(
            "nothing to set: give --new-unit, --new-baud, --power-on, --ppr or --set".into(),
        ));
    }
    Ok(out)
}

/// Asks on the terminal; anything but y/yes refuses.
async fn confirm(question: String) -> bool {
    eprint!("{question} [y/N] ");
    let _ = std::io::stderr().flush();
    let answer = tokio::task::spawn_blocking(|| {
        let mut s = String::new();
        std::io::stdin().read_line(&mut s).map(|_| s)
    })
    .await;
    matches!(answer, Ok(Ok(s)) if matches!(s.trim(), "y" | "Y" | "yes"))
}

async fn setup(
    m: &ModuleArgs,
    wanted: &[Wanted],
    yes: bool,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    use super::modbus::setup::*;
    let target = target(&m.at.line)?;
    let (unit, baud) = (m.at.unit()?, m.at.baud());
    let mut link = target.open(baud)?;
    let profile =
        super::modbus::read::resolve_model(&mut link, &target, profiles, unit, &m.model, baud)
            .await?;
    let answer =
        m.at.line
            .timeout
            .map(Into::into)
            .unwrap_or(profile.answer_timeout);
    let timeout = link.timeout_for(answer, 1);
    let modes = crate::driver::modbus::probe::read_modes(&mut link, unit, &profile, timeout)
        .await
        .map_err(CommissionError::Failed)?;
    let channels = profile
        .channels(&modes)
        .map_err(|e| CommissionError::Failed(e.to_string()))?;
    let changes = plan_changes(&profile, &channels, wanted)?;
    refuse_taken_unit(&mut link, &changes, unit, profiles, answer).await?;
    let words = current_words(&mut link, &target, unit, &changes, answer).await?;
    let plan = describe_plan(unit, &profile.model, &changes, &words);
    eprint!("{plan}");
    if !yes && !confirm("write these settings?".into()).await {
        return Err(CommissionError::BadInput(
            "not confirmed; nothing written".into(),
        ));
    }
    write_changes(&mut link, &target, unit, &changes, &words, answer).await?;
    drop(link);
    let (unit, baud) = read_back(&target, &changes, unit, baud, &profile).await?;
    println!("written and read back at unit {unit}, {baud} baud:");
    let mut seen = std::collections::BTreeSet::new();
    for c in &changes {
        if seen.insert(c.setting.name.clone()) {
            println!("  {}", explain(c, unit));
        }
    }
    Ok(())
}

/// A new unit id that another module already answers at is refused before anything is written.
async fn refuse_taken_unit(
    link: &mut crate::driver::modbus::link::Link,
    changes: &[super::modbus::setup::Change],
    unit: u8,
    profiles: &Profiles,
    answer: std::time::Duration,
) -> Result<(), CommissionError> {
    let Some(c) = changes.iter().find(|c| c.setting.name == "unit") else {
        return Ok(());
    };
    let new = c.field as u8;
    if new == unit {
        return Ok(());
    }
    let id_timeout = link.timeout_for(answer, 3);
    if let Ok(Some(_)) =
        crate::driver::modbus::probe::identify(link, profiles, new, id_timeout, true).await
    {
        return Err(CommissionError::BadInput(format!(
            "unit {new} already answers on this line; choose a free unit id"
        )));
    }
    Ok(())
}

/// What `setup` will write, a line a setting (sixteen counters changed alike are one line).
fn describe_plan(
    unit: u8,
    model: &str,
    changes: &[super::modbus::setup::Change],
    words: &[u16],
) -> String {
    let mut plan = format!("unit {unit} ({model}):\n");
    let mut lines: Vec<(String, usize)> = Vec::new();
    for (c, w) in changes.iter().zip(words) {
        let from_to = format!(
            "{} -> {}",
            c.setting.describe(c.setting.field(*w)),
            c.setting.describe(c.field)
        );
        // Sixteen counters changed alike are one line.
        let key = format!("{}: {from_to}", c.setting.name);
        match lines.last_mut() {
            Some((k, n)) if *k == key && c.label != c.setting.name => *n += 1,
            _ => lines.push((
                if c.label.contains('#') {
                    key
                } else {
                    format!("{}: {from_to}", c.label)
                },
                1,
            )),
        }
    }
    for (line, n) in lines {
        let times = if n > 1 {
            format!(" (x{n})")
        } else {
            String::new()
        };
        plan += &format!("  {line}{times}\n");
    }
    plan
}

async fn raw(
    line: &LineArgs,
    baud: u32,
    unit: u8,
    op: RawOp,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let target = target(line)?;
    if target.is_serial() {
        super::modbus::scan::scan_bauds(&baud.to_string(), profiles)?;
    }
    let answer = answer_time(line, profiles);
    let mut link = target.open(baud)?;
    match op {
        RawOp::Read { start, count } => {
            let words =
                super::modbus::raw::read(&mut link, &target, unit, start, count, answer).await?;
            print!("{}", super::modbus::raw::words_table(start, &words));
        }
        RawOp::Write {
            address,
            values,
            yes,
        } => {
            if !yes
                && !confirm(format!(
                    "write {values:?} at register {address} of unit {unit}?"
                ))
                .await
            {
                return Err(CommissionError::BadInput(
                    "not confirmed; nothing written".into(),
                ));
            }
            super::modbus::raw::write(&mut link, &target, unit, address, &values, answer).await?;
            println!("unit {unit}: wrote {values:?} at {address}");
        }
    }
    Ok(())
}

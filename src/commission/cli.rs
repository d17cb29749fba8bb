//! The commissioning subcommands of `pulsegate` (clap) and their terminal output.

use std::io::{IsTerminal, Write as _};
use std::path::PathBuf;
use std::process::ExitCode;
use std::time::Duration;

use tokio_util::sync::CancellationToken;

use super::error::CommissionError;
use super::line::Target;
use super::scan::ScanEvent;
use super::setup::Wanted;
use crate::command::Op;
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
    /// Serial parity: none | even | odd.
    #[arg(long, default_value = "none")]
    parity: String,
    /// Answer timeout before line time is added (default: the models' 100 ms).
    #[arg(long)]
    timeout: Option<humantime::Duration>,
}

/// One unit on the line: where, at what speed, which id.
#[derive(clap::Args, Debug, Clone)]
pub struct UnitArgs {
    #[command(flatten)]
    line: LineArgs,
    /// Baud rate to talk at.
    #[arg(long, default_value_t = 9600)]
    baud: u32,
    /// Unit id of the module.
    #[arg(long, value_parser = clap::value_parser!(u8).range(1..=247))]
    unit: u8,
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
    /// Find the units that answer on a line, their models and baud rates.
    Scan {
        #[command(flatten)]
        line: LineArgs,
        /// A baud rate, or "all": every rate the profiles support, fastest first.
        #[arg(long, default_value = "9600")]
        baud: String,
        /// Unit ids to ask: "1-247", "5", "1,3,10-20".
        #[arg(long, default_value = "1-247")]
        units: String,
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
    /// Read one module's channels, decoded as the gateway publishes them.
    Read {
        #[command(flatten)]
        module: ModuleArgs,
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
        #[arg(value_parser = super::raw::parse_u16)]
        start: u16,
        #[arg(value_parser = super::raw::parse_u16, default_value = "1")]
        count: u16,
    },
    /// Write VALUES from ADDRESS (one: FC06, more: FC16).
    Write {
        #[arg(value_parser = super::raw::parse_u16)]
        address: u16,
        #[arg(value_parser = super::raw::parse_u16, required = true)]
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
    Target::parse(line.port.clone(), line.host.clone(), &line.parity)
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
            scan(&line, &baud, &units, how, &profiles).await
        }
        Commission::Read {
            module,
            json,
            watch,
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
        Commission::Raw { at, op } => raw(&at.line, at.baud, at.unit, op, &profiles).await,
    }
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
    let bauds = super::scan::scan_bauds(baud, profiles)?;
    target.check_free()?;
    let cancel = ctrl_c();
    let tty = std::io::stderr().is_terminal();
    let mut progress = |e: ScanEvent<'_>| progress(e, tty);
    let plan = super::scan::ScanPlan {
        bauds,
        units,
        answer: answer_time(line, profiles),
        every_probe,
    };
    let outcome = super::scan::scan_line(&target, &plan, profiles, &cancel, &mut progress).await?;
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
            super::snippet::config_snippet(&target, &outcome.found)
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
    let mut link = target.open(m.at.baud)?;
    let profile =
        super::read::resolve_model(&mut link, &target, profiles, m.at.unit, &m.model, m.at.baud)
            .await?;
    let mut rt = super::read::poller(&target, m.at.baud, m.at.unit, &profile, &link);
    let Some(every) = watch.map(Duration::from) else {
        let value =
            super::read::read_once(&mut rt, &mut link, &profile, &target, m.at.baud).await?;
        if json {
            println!("{value}");
        } else {
            print!("{}", super::read::table(&value, None));
        }
        return Ok(());
    };
    let cancel = ctrl_c();
    let tty = std::io::stdout().is_terminal();
    let mut previous = None;
    while !cancel.is_cancelled() {
        let value =
            super::read::read_once(&mut rt, &mut link, &profile, &target, m.at.baud).await?;
        if json {
            println!("{value}");
        } else {
            if tty {
                print!("\x1b[H\x1b[J");
            }
            print!("{}", super::read::table(&value, previous.as_ref()));
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
    let mut link = target.open(m.at.baud)?;
    let profile =
        super::read::resolve_model(&mut link, &target, profiles, m.at.unit, &m.model, m.at.baud)
            .await?;
    if !profile.all_channels().iter().any(|c| c.name == channel) {
        return Err(CommissionError::BadInput(format!(
            "model {} has no channel {channel}",
            profile.model
        )));
    }
    let mut rt = super::read::poller(&target, m.at.baud, m.at.unit, &profile, &link);
    let got = super::read::write_count(&mut rt, &mut link, &target, channel, op).await?;
    let what = if matches!(op, Op::Clear) {
        "cleared"
    } else {
        "preset"
    };
    match got {
        Some(v) => println!("unit {} {channel}: {what}; reads back {v}", m.at.unit),
        None => println!("unit {} {channel}: {what}", m.at.unit),
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
    use super::setup::*;
    let target = target(&m.at.line)?;
    let mut link = target.open(m.at.baud)?;
    let profile =
        super::read::resolve_model(&mut link, &target, profiles, m.at.unit, &m.model, m.at.baud)
            .await?;
    let answer =
        m.at.line
            .timeout
            .map(Into::into)
            .unwrap_or(profile.answer_timeout);
    let timeout = link.timeout_for(answer, 1);
    let modes = crate::driver::modbus::probe::read_modes(&mut link, m.at.unit, &profile, timeout)
        .await
        .map_err(CommissionError::Failed)?;
    let channels = profile
        .channels(&modes)
        .map_err(|e| CommissionError::Failed(e.to_string()))?;
    let changes = plan_changes(&profile, &channels, wanted)?;
    if let Some(c) = changes.iter().find(|c| c.setting.name == "unit") {
        let new = c.field as u8;
        if new != m.at.unit {
            let id_timeout = link.timeout_for(answer, 3);
            if let Ok(Some(_)) =
                crate::driver::modbus::probe::identify(&mut link, profiles, new, id_timeout, true)
                    .await
            {
                return Err(CommissionError::BadInput(format!(
                    "unit {new} already answers on this line; choose a free unit id"
                )));
            }
        }
    }
    let words = current_words(&mut link, &target, m.at.unit, &changes, answer).await?;
    let mut plan = format!("unit {} ({}):\n", m.at.unit, profile.model);
    let mut lines: Vec<(String, usize)> = Vec::new();
    for (c, w) in changes.iter().zip(&words) {
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
    eprint!("{plan}");
    if !yes && !confirm("write these settings?".into()).await {
        return Err(CommissionError::BadInput(
            "not confirmed; nothing written".into(),
        ));
    }
    write_changes(&mut link, &target, m.at.unit, &changes, &words, answer).await?;
    drop(link);
    let (unit, baud) = read_back(&target, &changes, m.at.unit, m.at.baud, &profile).await?;
    println!("written and read back at unit {unit}, {baud} baud:");
    let mut seen = std::collections::BTreeSet::new();
    for c in &changes {
        if seen.insert(c.setting.name.clone()) {
            println!("  {}", explain(c, m.at.unit));
        }
    }
    Ok(())
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
        super::scan::scan_bauds(&baud.to_string(), profiles)?;
    }
    let answer = answer_time(line, profiles);
    let mut link = target.open(baud)?;
    match op {
        RawOp::Read { start, count } => {
            let words = super::raw::read(&mut link, &target, unit, start, count, answer).await?;
            print!("{}", super::raw::words_table(start, &words));
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
            super::raw::write(&mut link, &target, unit, address, &values, answer).await?;
            println!("unit {unit}: wrote {values:?} at {address}");
        }
    }
    Ok(())
}

//! The commissioning subcommands on a Modbus line: scan, read, clear and preset, setup, raw.

use std::io::{IsTerminal, Write as _};
use std::time::Duration;

use super::scan::ScanEvent;
use super::setup::Wanted;
use crate::command::Op;
use crate::commission::cli::{LineArgs, ModuleArgs, RawOp, ScanHow, ctrl_c, target};
use crate::commission::error::CommissionError;
use crate::outcome::Found;
use crate::profile::Profiles;

/// A module a command names: its line opened at its baud rate and its model resolved
/// (`auto` asks the module).
struct Module {
    target: crate::commission::target::Target,
    link: crate::modbus::driver::link::Link,
    unit: u8,
    baud: u32,
    profile: std::sync::Arc<crate::profile::Profile>,
}

async fn module(m: &ModuleArgs, profiles: &Profiles) -> Result<Module, CommissionError> {
    let target = target(&m.at.line)?;
    let (unit, baud) = (m.at.unit()?, m.at.baud());
    let mut link = target.open(baud)?;
    let profile =
        super::read::resolve_model(&mut link, &target, profiles, unit, &m.model, baud).await?;
    Ok(Module {
        target,
        link,
        unit,
        baud,
        profile,
    })
}

fn answer_time(line: &LineArgs, profiles: &Profiles) -> Duration {
    line.timeout
        .map(Into::into)
        .unwrap_or_else(|| crate::modbus::driver::probe::answer_time(profiles))
}

pub(crate) async fn scan(
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
        crate::modbus::driver::probe::parse_units(units).map_err(CommissionError::BadInput)?;
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

pub(crate) async fn read(
    m: &ModuleArgs,
    json: bool,
    watch: Option<humantime::Duration>,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let Module {
        target,
        mut link,
        unit,
        baud,
        profile,
    } = module(m, profiles).await?;
    let mut rt = super::read::poller(&target, baud, unit, &profile, &link);
    let Some(every) = watch.map(Duration::from) else {
        let value = super::read::read_once(&mut rt, &mut link, &profile, &target, baud).await?;
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
        let value = super::read::read_once(&mut rt, &mut link, &profile, &target, baud).await?;
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

pub(crate) async fn write_count(
    m: &ModuleArgs,
    channel: &str,
    op: Op,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    let Module {
        target,
        mut link,
        unit,
        baud,
        profile,
    } = module(m, profiles).await?;
    if !profile.all_channels().iter().any(|c| c.name == channel) {
        return Err(CommissionError::BadInput(format!(
            "model {} has no channel {channel}",
            profile.model
        )));
    }
    let mut rt = super::read::poller(&target, baud, unit, &profile, &link);
    let got = super::read::write_count(&mut rt, &mut link, &target, channel, op).await?;
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
pub(crate) fn wanted(
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

pub(crate) async fn setup(
    m: &ModuleArgs,
    wanted: &[Wanted],
    yes: bool,
    profiles: &Profiles,
) -> Result<(), CommissionError> {
    use super::setup::*;
    let Module {
        target,
        mut link,
        unit,
        baud,
        profile,
    } = module(m, profiles).await?;
    let answer =
        m.at.line
            .timeout
            .map(Into::into)
            .unwrap_or(profile.answer_timeout);
    let timeout = link.timeout_for(answer, 1);
    let modes = crate::modbus::driver::probe::read_modes(&mut link, unit, &profile, timeout)
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
    link: &mut crate::modbus::driver::link::Link,
    changes: &[super::setup::Change],
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
        crate::modbus::driver::probe::identify(link, profiles, new, id_timeout, true).await
    {
        return Err(CommissionError::BadInput(format!(
            "unit {new} already answers on this line; choose a free unit id"
        )));
    }
    Ok(())
}

/// What `setup` will write, a line a setting (sixteen counters changed alike are one line).
fn describe_plan(unit: u8, model: &str, changes: &[super::setup::Change], words: &[u16]) -> String {
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

pub(crate) async fn raw(
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

//! The commissioning subcommands on an M-Bus segment: scan (primary addresses or the wildcard
//! search) and read one meter.

use std::io::IsTerminal;

use crate::commission::cli::{LineArgs, ScanHow, UnitArgs, ctrl_c};
use crate::commission::error::CommissionError;
use crate::commission::target::Target;

/// The M-Bus segment of `line` at `baud` (default 2400, even parity).
fn segment(line: &LineArgs, baud: Option<u32>) -> Result<super::Segment, CommissionError> {
    let parity = line.parity.as_deref().unwrap_or("even");
    Ok(super::Segment {
        target: Target::parse(line.port.clone(), line.host.clone(), parity)?,
        baud: baud.unwrap_or(2400),
        timeout: line.timeout.map(Into::into),
    })
}

/// `scan --protocol mbus`: primary addresses, or `--secondary` the wildcard search.
pub(crate) async fn scan_meters(
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
    let scan = super::MeterScan {
        secondary,
        addresses: super::parse_addresses(units.as_deref().unwrap_or("0-250"))?,
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
        super::scan(&segment, line.host.as_deref(), &scan, &cancel, progress).await?;
    if tty {
        eprint!("\r\x1b[K");
    }
    for p in &problems {
        eprintln!("  {p}");
    }
    if secondary {
        eprintln!("{collisions} collision(s) resolved digit by digit");
    }
    let table = super::found_table(&found);
    if how.toml {
        eprint!("{table}");
        print!("{}", super::config_snippet(&segment, &found));
    } else if how.json {
        let list: Vec<_> = found.iter().map(super::found_json).collect();
        let out = serde_json::json!({ "found": list, "collisions": collisions,
            "problems": problems, "interrupted": cancel.is_cancelled() });
        println!("{out}");
    } else {
        print!("{table}");
    }
    Ok(())
}

/// `read --protocol mbus`: one meter's answer.
pub(crate) async fn read_meter(
    at: &UnitArgs,
    address: Option<u8>,
    id: Option<&str>,
    json: bool,
) -> Result<(), CommissionError> {
    let segment = segment(&at.line, at.baud)?;
    let meter = super::meter_at(address, id)?;
    let (header, records) = super::read(&segment, at.line.host.as_deref(), meter).await?;
    let answer = super::answer_json(&header, &records);
    if json {
        println!("{answer}");
    } else {
        print!("{}", super::answer_table(&answer, &records));
    }
    Ok(())
}

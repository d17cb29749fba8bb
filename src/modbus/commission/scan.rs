//! `pulsegate scan`: which units answer on a line, at which baud rate, and which model each is.

use std::time::Duration;

use tokio_util::sync::CancellationToken;

use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::modbus::driver::link::LinkError;
use crate::modbus::driver::probe::{describe, identify};
use crate::outcome::Found;
use crate::profile::Profiles;

/// What happened during a scan, for progress display.
#[derive(Debug)]
pub enum ScanEvent<'a> {
    /// Starting on one baud rate (`None`: TCP) with `units` units; about `estimate` if none
    /// answers.
    Baud {
        baud: Option<u32>,
        units: usize,
        estimate: Duration,
    },
    /// About to ask the `index`-th unit.
    Asking {
        unit: u8,
        index: usize,
        of: usize,
    },
    Found(&'a Found),
    /// Bytes came back but never a valid frame: something is there at another speed or parity.
    Garbled {
        baud: Option<u32>,
        unit: u8,
    },
}

/// The outcome of a scan; `interrupted` when Ctrl-C stopped it early.
#[derive(Debug, Default)]
pub struct ScanOutcome {
    pub found: Vec<Found>,
    pub interrupted: bool,
}

/// The baud rates to try: one given, or with "all" every rate a profile supports, fastest first.
pub fn scan_bauds(text: &str, profiles: &Profiles) -> Result<Vec<u32>, CommissionError> {
    let mut all: Vec<u32> = crate::modbus::driver::probe::distinct(profiles)
        .iter()
        .flat_map(|p| p.bauds.iter().copied())
        .collect();
    all.sort_unstable_by(|a, b| b.cmp(a));
    all.dedup();
    if text == "all" {
        return Ok(all);
    }
    let baud: u32 = text
        .parse()
        .map_err(|_| CommissionError::BadInput(format!("--baud {text:?}: a rate or \"all\"")))?;
    if !all.contains(&baud) {
        return Err(CommissionError::BadInput(format!(
            "--baud {baud}: no model supports it ({all:?})"
        )));
    }
    Ok(vec![baud])
}

/// What to scan: which units at which baud rates (ignored on TCP), how long to wait for an
/// answer, and whether to ask every identification register of a silent unit.
#[derive(Debug, Clone)]
pub struct ScanPlan {
    pub bauds: Vec<u32>,
    pub units: Vec<u8>,
    pub answer: Duration,
    pub every_probe: bool,
}

/// Scans as `plan` says until done or `cancel`.
pub async fn scan_line(
    target: &Target,
    plan: &ScanPlan,
    profiles: &Profiles,
    cancel: &CancellationToken,
    on_event: &mut dyn FnMut(ScanEvent<'_>),
) -> Result<ScanOutcome, CommissionError> {
    let ScanPlan {
        bauds,
        units,
        answer,
        every_probe,
    } = plan;
    let (answer, every_probe) = (*answer, *every_probe);
    let mut outcome = ScanOutcome::default();
    let bauds: Vec<Option<u32>> = if target.is_serial() {
        bauds.iter().map(|b| Some(*b)).collect()
    } else {
        vec![None]
    };
    for baud in bauds {
        let mut link = target.open(baud.unwrap_or(9600))?;
        let timeout = link.timeout_for(answer, 3);
        let per_unit = timeout
            + link
                .timing()
                .map(|t| t.silent_interval())
                .unwrap_or_default();
        on_event(ScanEvent::Baud {
            baud,
            units: units.len(),
            estimate: per_unit * units.len() as u32,
        });
        for (index, &unit) in units.iter().enumerate() {
            on_event(ScanEvent::Asking {
                unit,
                index,
                of: units.len(),
            });
            let answer = tokio::select! {
                a = identify(&mut link, profiles, unit, timeout, every_probe) => a,
                () = cancel.cancelled() => {
                    outcome.interrupted = true;
                    return Ok(outcome);
                }
            };
            let identified = match answer {
                Ok(Some(i)) => i,
                Ok(None) => continue,
                Err(LinkError::Garbled(..)) => {
                    on_event(ScanEvent::Garbled { baud, unit });
                    continue;
                }
                Err(e @ (LinkError::Open { .. } | LinkError::Io(_))) => {
                    return Err(target.error(unit, e));
                }
                Err(_) => continue,
            };
            let found = describe(&mut link, baud, unit, identified, timeout, None).await;
            on_event(ScanEvent::Found(&found));
            outcome.found.push(found);
        }
    }
    Ok(outcome)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn all_bauds_are_the_profiles_rates_fastest_first() {
        let p = Profiles::builtin();
        assert_eq!(
            scan_bauds("all", &p).unwrap(),
            [115200, 57600, 38400, 19200, 9600, 4800, 2400]
        );
        assert_eq!(scan_bauds("19200", &p).unwrap(), [19200]);
        assert!(scan_bauds("14400", &p).is_err());
    }
}

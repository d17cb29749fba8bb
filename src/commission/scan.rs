//! `pulsegate scan`: which units answer on a line, at which baud rate, and which model each is.

use std::time::Duration;

use tokio_util::sync::CancellationToken;

use super::CommissionError;
use super::identify::{Identified, identify};
use super::line::{Target, timeout_for};
use crate::driver::modbus::link::{Link, LinkError};
use crate::outcome::Found;
use crate::profile::{Profile, Profiles};

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

/// Unit ids from "1-247", "5" or "1,3,10-20"; 0 and 248.. are refused.
pub fn parse_units(text: &str) -> Result<Vec<u8>, CommissionError> {
    let bad = |why: String| CommissionError::BadInput(format!("--units {text:?}: {why}"));
    let mut out = Vec::new();
    for part in text.split(',') {
        let part = part.trim();
        let (lo, hi) = part.split_once('-').unwrap_or((part, part));
        let parse = |s: &str| {
            s.trim()
                .parse::<u16>()
                .map_err(|_| bad(format!("{s:?} is not a unit id")))
        };
        let (lo, hi) = (parse(lo)?, parse(hi)?);
        if lo == 0 || hi > 247 {
            return Err(bad("unit ids are 1..=247".into()));
        }
        if lo > hi {
            return Err(bad(format!("{lo}-{hi} runs backwards")));
        }
        out.extend((lo..=hi).map(|u| u as u8));
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

/// The baud rates to try: one given, or with "all" every rate a profile supports, fastest first.
pub fn scan_bauds(text: &str, profiles: &Profiles) -> Result<Vec<u32>, CommissionError> {
    let mut all: Vec<u32> = super::identify::distinct(profiles)
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

/// The answer time to wait for on a scan: the slowest model's.
pub fn answer_time(profiles: &Profiles) -> Duration {
    super::identify::distinct(profiles)
        .iter()
        .map(|p| p.answer_timeout)
        .max()
        .unwrap_or(Duration::from_millis(100))
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
        let timeout = timeout_for(answer, &link, 3);
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

/// A found unit with its work modes and channels read.
/// Reading the work modes is skipped when each mode read could take `timeout` and they might
/// not be done by `deadline` (a running bus's next poll).
pub(crate) async fn describe(
    link: &mut Link,
    baud: Option<u32>,
    unit: u8,
    identified: Identified,
    timeout: Duration,
    deadline: Option<tokio::time::Instant>,
) -> Found {
    let mut found = Found {
        baud,
        unit,
        model: None,
        modes: Vec::new(),
        channels: Vec::new(),
        note: None,
    };
    match identified {
        Identified::Unknown(seen) => {
            found.note = Some(if seen.is_empty() {
                "answers, but refused every identification read".into()
            } else {
                format!("answers, but no profile matches its identification {seen:04X?}")
            });
        }
        Identified::Model(profile) => {
            found.model = Some(profile.model.clone());
            let worst = timeout * profile.mode_registers().len() as u32;
            if deadline.is_some_and(|d| tokio::time::Instant::now() + worst > d) {
                found.note = Some("work modes not read: no idle line time for them".into());
                return found;
            }
            match read_modes(link, unit, &profile, timeout).await {
                Ok(modes) => match profile.channels(&modes) {
                    Ok(ch) => {
                        found.channels = ch.into_iter().map(|c| c.name).collect();
                        found.modes = modes;
                    }
                    Err(e) => found.note = Some(e.to_string()),
                },
                Err(e) => found.note = Some(format!("work modes not readable: {e}")),
            }
        }
    }
    found
}

/// The raw work-mode registers of a module, one read per register (they may not be adjacent).
pub(super) async fn read_modes(
    link: &mut Link,
    unit: u8,
    profile: &Profile,
    timeout: Duration,
) -> Result<Vec<u16>, String> {
    let mut modes = Vec::new();
    for r in profile.mode_registers() {
        match link.read(unit, r.address, 1, timeout).await {
            Ok(Ok(w)) => modes.push(w[0]),
            Ok(Err(e)) => return Err(format!("register {} refused: {e:?}", r.address)),
            Err(e) => return Err(e.to_string()),
        }
    }
    Ok(modes)
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn unit_lists_and_ranges_are_read_and_bad_ones_refused() {
        assert_eq!(parse_units("1-3,7,2").unwrap(), [1, 2, 3, 7]);
        assert_eq!(parse_units("1-247").unwrap().len(), 247);
        for bad in ["0-5", "1-248", "5-1", "x", ""] {
            assert!(parse_units(bad).is_err(), "{bad}");
        }
    }

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

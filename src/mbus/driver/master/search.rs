//! Finding meters on a segment: primary addresses asked one by one (`SND_NKE`, `REQ_UD2`), and
//! the standard's wildcard search by secondary address: select `0FFFFFFF` … `9FFFFFFF`; no
//! answer is no meter, one answer is one meter (read at 253 for its whole id), a garbled one is
//! several at once (a collision), so the search goes one digit deeper there.

use super::link::{Heard, Link, LinkError};
use crate::mbus::driver::address::{SecondaryAddress, SecondaryMask};
use crate::mbus::driver::frame::{self, Frame, SELECTED};
use crate::mbus::driver::header::Header;
use crate::mbus::driver::{Telegram, decode_frame};

/// A meter a scan found.
#[derive(Debug, Clone, PartialEq)]
pub struct FoundMeter {
    /// Its id, manufacturer, version and medium (from its answer's long header).
    pub secondary: Option<SecondaryAddress>,
    /// The primary address it answered at (its answer's address byte).
    pub primary: u8,
    /// Its first telegram.
    pub telegram: Telegram,
}

/// What a primary address gave.
#[derive(Debug, Clone, PartialEq)]
pub enum Probe {
    Nothing,
    Found(Box<FoundMeter>),
    /// Bytes that were no frame: several meters at this address, or a broken one.
    Garbled(String),
    /// A frame that could not be decoded.
    Undecodable(String),
}

/// Asks primary address `address`: `SND_NKE`, then `REQ_UD2` (FCB set: the first after a
/// reset).
pub async fn probe_primary(link: &mut Link, address: u8) -> Result<Probe, LinkError> {
    match link.exchange(&frame::snd_nke(address)).await? {
        Heard::Nothing => return Ok(Probe::Nothing),
        Heard::Garbled { why, .. } => return Ok(Probe::Garbled(why)),
        Heard::Frame(_) => {}
    }
    read_at(link, address).await
}

/// Reads the first telegram at `address` (after a reset or a select).
async fn read_at(link: &mut Link, address: u8) -> Result<Probe, LinkError> {
    let frame = match link.exchange(&frame::req_ud2(address, true)).await? {
        Heard::Nothing => return Ok(Probe::Nothing),
        Heard::Garbled { why, .. } => return Ok(Probe::Garbled(why)),
        Heard::Frame(f) => f,
    };
    let primary = match &frame {
        Frame::Long { address, .. } | Frame::Control { address, .. } => *address,
        _ => address,
    };
    Ok(match decode_frame(&frame) {
        Ok(telegram) => Probe::Found(Box::new(FoundMeter {
            secondary: telegram.header.address().copied(),
            primary,
            telegram,
        })),
        Err(e) => Probe::Undecodable(e.to_string()),
    })
}

/// Selects the meters matching `mask` and reads the one selected.
pub async fn probe_secondary(link: &mut Link, mask: &SecondaryMask) -> Result<Probe, LinkError> {
    match link.exchange(&frame::select(mask)).await? {
        Heard::Nothing => Ok(Probe::Nothing),
        Heard::Garbled { why, .. } => Ok(Probe::Garbled(why)),
        Heard::Frame(Frame::Ack) => read_at(link, SELECTED).await,
        Heard::Frame(other) => Ok(Probe::Garbled(format!("{other:?} answered a select"))),
    }
}

/// What happened at one step of a secondary search, as it happens.
#[derive(Debug)]
pub enum Step<'a> {
    /// A mask was asked (its id text, F for the wildcard digits).
    Asked(&'a str),
    /// Several meters answered a mask: the search goes a digit deeper.
    Collision(&'a str),
    Found(&'a FoundMeter),
}

/// The outcome of a secondary search.
#[derive(Debug, Default)]
pub struct Searched {
    pub found: Vec<FoundMeter>,
    /// Masks several meters answered (resolved a digit deeper, except at the eighth).
    pub collisions: usize,
    /// Masks whose meter answered something that is no telegram.
    pub problems: Vec<String>,
    /// The search was stopped before its end.
    pub interrupted: bool,
}

/// The wildcard search over the whole id space; `step` hears each step (and may stop the
/// search by returning `false`).
pub async fn secondary(
    link: &mut Link,
    mut step: impl FnMut(Step<'_>) -> bool,
) -> Result<Searched, LinkError> {
    let mut out = Searched::default();
    let mut todo = vec![String::new()];
    while let Some(prefix) = todo.pop() {
        for d in (0..=9).rev() {
            let digits = format!("{prefix}{d}");
            let text = format!("{digits:F<8}");
            if !step(Step::Asked(&text)) {
                out.interrupted = true;
                return Ok(out);
            }
            let mask = SecondaryMask::from_id(&text).unwrap_or(SecondaryMask::ANY);
            match probe_secondary(link, &mask).await? {
                Probe::Nothing => {}
                Probe::Found(m) => {
                    step(Step::Found(&m));
                    out.found.push(*m);
                }
                Probe::Garbled(_) if digits.len() < 8 => {
                    out.collisions += 1;
                    step(Step::Collision(&text));
                    todo.push(digits);
                }
                Probe::Garbled(why) | Probe::Undecodable(why) => {
                    out.problems.push(format!("{text}: {why}"));
                }
            }
        }
    }
    // Nothing stays selected behind the search.
    let _ = link.exchange(&frame::snd_nke(SELECTED)).await?;
    out.found.sort_by_key(|m| m.secondary.map(|s| s.id));
    Ok(out)
}

/// The medium of a found meter.
pub fn medium(m: &FoundMeter) -> Option<u8> {
    match m.telegram.header {
        Header::Long { address, .. } => Some(address.medium),
        Header::Fixed { medium, .. } => Some(medium),
        _ => None,
    }
}

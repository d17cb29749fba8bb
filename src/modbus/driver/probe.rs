//! Asking a unit what it is, for a scan (`pulsegate scan` and idle-time surveys alike): its model
//! from the identification registers (profile data: `[identify]`), its work modes and channels,
//! and which units a scan asks.

use std::sync::Arc;
use std::time::Duration;

use tokio_modbus::ExceptionCode;

use super::link::{Link, LinkError};
use crate::outcome::Found;
use crate::profile::{Profile, Profiles};

/// What a unit that answered turned out to be.
#[derive(Debug, Clone)]
pub enum Identified {
    Model(Arc<Profile>),
    /// It answered, but no profile's identification matched; the words it gave, if any.
    Unknown(Vec<(u16, Vec<u16>)>),
}

/// Each distinct profile once (aliases share one).
pub(crate) fn distinct(profiles: &Profiles) -> Vec<Arc<Profile>> {
    let mut out: Vec<Arc<Profile>> = Vec::new();
    for name in profiles.names() {
        if let Some(p) = profiles.get(name)
            && !out.iter().any(|o| o.model == p.model)
        {
            out.push(p);
        }
    }
    out
}

/// The identification reads to try, as (address, registers): the one most profiles share first,
/// so an empty unit costs one timeout.
pub(crate) fn probes(profiles: &Profiles) -> Vec<(u16, u16)> {
    let mut probes: Vec<((u16, u16), usize)> = Vec::new();
    for p in distinct(profiles) {
        if let Some((address, words)) = &p.identify {
            let key = (*address, words.len() as u16);
            match probes.iter_mut().find(|(k, _)| *k == key) {
                Some((_, n)) => *n += 1,
                None => probes.push((key, 1)),
            }
        }
    }
    probes.sort_by(|a, b| b.1.cmp(&a.1).then(a.0.cmp(&b.0)));
    probes.into_iter().map(|(k, _)| k).collect()
}

/// The profile whose identification is `words` at `address`, if any.
fn identify_words(profiles: &Profiles, address: u16, words: &[u16]) -> Option<Arc<Profile>> {
    distinct(profiles).into_iter().find(|p| {
        p.identify
            .as_ref()
            .is_some_and(|(a, w)| *a == address && w.as_slice() == words)
    })
}

/// Exceptions a Modbus TCP gateway gives for a unit behind it that is not there.
fn means_absent(e: ExceptionCode) -> bool {
    matches!(
        e,
        ExceptionCode::GatewayPathUnavailable | ExceptionCode::GatewayTargetDevice
    )
}

/// Asks `unit` for its identification. `Ok(None)`: nothing answered. A garbled answer is an
/// error: something is there, perhaps at another baud rate. With `every_probe`, silence on the
/// first identification read does not end the question (a module may stay silent on a
/// register it lacks instead of refusing it); without, an empty unit costs one timeout.
pub(crate) async fn identify(
    link: &mut Link,
    profiles: &Profiles,
    unit: u8,
    timeout: Duration,
    every_probe: bool,
) -> Result<Option<Identified>, LinkError> {
    let mut seen = Vec::new();
    let mut answered = false;
    for (i, (address, len)) in probes(profiles).into_iter().enumerate() {
        let answer = link.read(unit, address, len, timeout).await;
        answered |= !matches!(answer, Err(LinkError::Timeout(_)));
        match answer {
            Err(LinkError::Timeout(_)) if i == 0 && !every_probe => return Ok(None),
            Err(LinkError::Timeout(_)) => continue,
            Err(e) => return Err(e),
            Ok(Err(e)) if i == 0 && means_absent(e) => return Ok(None),
            Ok(Err(_)) => continue,
            Ok(Ok(words)) => {
                if let Some(p) = identify_words(profiles, address, &words) {
                    return Ok(Some(Identified::Model(p)));
                }
                seen.push((address, words));
            }
        }
    }
    Ok(answered.then_some(Identified::Unknown(seen)))
}

/// Unit ids of a scan (`--units`): the scan request's rule, shared with the MQTT scan.
pub use crate::scan::parse_units;

/// The answer time to wait for on a scan: the slowest model's.
pub fn answer_time(profiles: &Profiles) -> Duration {
    distinct(profiles)
        .iter()
        .map(|p| p.answer_timeout)
        .max()
        .unwrap_or(Duration::from_millis(100))
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
        meter: None,
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
pub(crate) async fn read_modes(
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
    fn the_register_three_models_share_is_asked_first() {
        // YL67/IBF67 and WJ157 keep their name at 40211 (offset 210); ZH-YX1600 at 0x0055..57.
        assert_eq!(probes(&Profiles::builtin()), [(210, 1), (0x0055, 3)]);
    }

    #[test]
    fn datasheet_names_identify_each_model() {
        let p = Profiles::builtin();
        // YL67.md 40211: "高位：0x00 低位：0x67"; WJ157.md: "高位: 0x01 低位: 0x50".
        assert_eq!(identify_words(&p, 210, &[0x0067]).unwrap().model, "yl67");
        assert_eq!(identify_words(&p, 210, &[0x0150]).unwrap().model, "wj157");
        // ZH-YX1600.md 0x0055..0x0057: 0x5958 "YX", 0x3136 "16", 0x3030 "00".
        let zh = identify_words(&p, 0x55, &[0x5958, 0x3136, 0x3030]).unwrap();
        assert_eq!(zh.model, "zh-yx1600");
        assert!(identify_words(&p, 210, &[0x0157]).is_none());
    }
}

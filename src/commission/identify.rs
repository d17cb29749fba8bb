//! Telling a module's model from its identification registers (profile data: `[identify]`).

use std::sync::Arc;
use std::time::Duration;

use tokio_modbus::ExceptionCode;

use crate::driver::modbus::link::{Link, LinkError};
use crate::profile::{Profile, Profiles};

/// What a unit that answered turned out to be.
#[derive(Debug, Clone)]
pub enum Identified {
    Model(Arc<Profile>),
    /// It answered, but no profile's identification matched; the words it gave, if any.
    Unknown(Vec<(u16, Vec<u16>)>),
}

/// Each distinct profile once (aliases share one).
pub(super) fn distinct(profiles: &Profiles) -> Vec<Arc<Profile>> {
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
pub(super) fn probes(profiles: &Profiles) -> Vec<(u16, u16)> {
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
pub fn identify_words(profiles: &Profiles, address: u16, words: &[u16]) -> Option<Arc<Profile>> {
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

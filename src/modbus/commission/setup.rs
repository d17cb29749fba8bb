//! `pulsegate setup`: change the settings a module's datasheet documents (profile data), after
//! confirmation, read back, with what happens next explained. There is no factory reset.

use std::sync::Arc;

use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::modbus::driver::link::Link;
use crate::profile::{Applies, ChannelSpec, Place, Profile, Setting};

/// One requested change: setting name, channel (per-channel settings), value as typed.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Wanted {
    pub setting: String,
    pub channel: Option<String>,
    pub value: String,
}

/// A checked change to one register.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Change {
    pub setting: Setting,
    /// "unit", "ppr enc0", "power_on #3".
    pub label: String,
    pub register: u16,
    /// The new value of the setting's field (already checked against the datasheet).
    pub field: u16,
}

/// Checks every wanted change against the profile; nothing is written when one is wrong.
/// `channels` are the module's channels in its current work modes.
/// A per-channel setting of channel `name`, where the module's current work modes have it.
fn channel_change(
    profile: &Profile,
    channels: &[ChannelSpec],
    w: &Wanted,
    setting: &crate::profile::Setting,
    name: &str,
    field: u16,
) -> Result<Change, CommissionError> {
    let bad = |e: String| CommissionError::BadInput(e);
    let ch = channels.iter().find(|c| c.name == name).ok_or_else(|| {
        bad(format!(
            "{} has no channel {name} in its current work modes (it has: {})",
            profile.model,
            channels
                .iter()
                .map(|c| c.name.as_str())
                .collect::<Vec<_>>()
                .join(", ")
        ))
    })?;
    let reg = ch
        .ppr
        .ok_or_else(|| bad(format!("channel {name} has no {} register", w.setting)))?;
    Ok(Change {
        setting: setting.clone(),
        label: format!("{} {name}", w.setting),
        register: reg.address,
        field,
    })
}

pub fn plan_changes(
    profile: &Profile,
    channels: &[ChannelSpec],
    wanted: &[Wanted],
) -> Result<Vec<Change>, CommissionError> {
    let bad = |e: String| CommissionError::BadInput(e);
    let mut out = Vec::new();
    for w in wanted {
        let setting = profile
            .setting(&w.setting)
            .map_err(|e| bad(e.to_string()))?;
        let field = setting.encode(&w.value).map_err(|e| bad(e.to_string()))?;
        match (&setting.place, &w.channel) {
            (Place::Channel(_), Some(name)) => {
                out.push(channel_change(profile, channels, w, setting, name, field)?);
            }
            (Place::Channel(_), None) => {
                return Err(bad(format!(
                    "{} is set per channel: give CHANNEL={}",
                    w.setting, w.value
                )));
            }
            (Place::Registers { .. }, Some(name)) => {
                return Err(bad(format!(
                    "{} is not a per-channel setting ({name})",
                    w.setting
                )));
            }
            (Place::Registers { .. }, None) => {
                let regs = setting.registers();
                let many = regs.len() > 1;
                for (i, register) in regs.into_iter().enumerate() {
                    out.push(Change {
                        setting: setting.clone(),
                        label: if many {
                            format!("{} #{}", w.setting, i + 1)
                        } else {
                            w.setting.clone()
                        },
                        register,
                        field,
                    });
                }
            }
        }
    }
    // The address goes last and the baud rate just before it: once either applies, the module
    // answers elsewhere.
    out.sort_by_key(|c| match c.setting.name.as_str() {
        "unit" => 2,
        "baud" => 1,
        _ => 0,
    });
    Ok(out)
}

/// What happens after the write, for people.
pub fn explain(change: &Change, unit: u8) -> String {
    let v = change.setting.describe(change.field);
    let what = match change.setting.name.as_str() {
        "unit" => format!("the module answers at unit {v}"),
        "baud" => format!("the module answers at {v} baud"),
        _ => format!("{} is {v}", change.setting.name),
    };
    match change.setting.applies {
        Applies::Now => format!("{what} from now on"),
        Applies::Restart => {
            let until = match change.setting.name.as_str() {
                "unit" => format!("until then it answers at unit {unit}"),
                "baud" => "until then it answers at its old rate".to_string(),
                _ => "until then the old value holds".to_string(),
            };
            format!(
                "{what} after its next power-up (the datasheet: takes effect after a \
                 restart); {until}"
            )
        }
        Applies::Unstated => {
            format!("{what} now or after its next power-up (the datasheet does not say which)")
        }
    }
}

/// Where the module answers right after the writes: (unit, baud) for reading back.
pub fn answers_at(changes: &[Change], unit: u8, baud: u32) -> Vec<(u8, u32)> {
    let now = |name: &str, applies: &[Applies]| {
        changes
            .iter()
            .find(|c| c.setting.name == name && applies.contains(&c.setting.applies))
            .map(|c| c.field)
    };
    let baud_of = |field: u16| {
        changes
            .iter()
            .find(|c| c.setting.name == "baud")
            .and_then(|c| c.setting.describe(field).parse::<u32>().ok())
            .unwrap_or(baud)
    };
    let unit_now = now("unit", &[Applies::Now]).map_or(unit, |u| u as u8);
    let mut out = vec![(unit_now, now("baud", &[Applies::Now]).map_or(baud, baud_of))];
    if let Some(b) = now("baud", &[Applies::Unstated]) {
        out.push((unit_now, baud_of(b)));
    }
    if let Some(u) = now("unit", &[Applies::Unstated]) {
        out.push((u as u8, out[0].1));
    }
    out
}

/// Reads the current word of each change's register.
pub(crate) async fn current_words(
    link: &mut Link,
    target: &Target,
    unit: u8,
    changes: &[Change],
    answer: std::time::Duration,
) -> Result<Vec<u16>, CommissionError> {
    let timeout = link.timeout_for(answer, 1);
    let mut out = Vec::new();
    for c in changes {
        match link.read(unit, c.register, 1, timeout).await {
            Ok(Ok(w)) => out.push(w[0]),
            Ok(Err(exception)) => {
                return Err(CommissionError::Refused {
                    unit,
                    what: format!("a read of {} (register {})", c.label, c.register),
                    exception: format!("{exception:?}"),
                });
            }
            Err(e) => return Err(target.error(unit, e)),
        }
    }
    Ok(out)
}

/// Writes the changes (each setting's bits only) at `unit`.
pub(crate) async fn write_changes(
    link: &mut Link,
    target: &Target,
    unit: u8,
    changes: &[Change],
    words: &[u16],
    answer: std::time::Duration,
) -> Result<(), CommissionError> {
    let timeout = link.timeout_for(answer, 1);
    for (c, word) in changes.iter().zip(words) {
        let value = c.setting.with_field(*word, c.field);
        match link.write_register(unit, c.register, value, timeout).await {
            Ok(Ok(())) => {}
            Ok(Err(exception)) => {
                return Err(CommissionError::Refused {
                    unit,
                    what: format!("the write of {} (register {})", c.label, c.register),
                    exception: format!("{exception:?}"),
                });
            }
            Err(e) => return Err(target.error(unit, e)),
        }
    }
    Ok(())
}

/// Reads the changes back where the module answers now; `Ok` with the (unit, baud) it answered at.
pub(crate) async fn read_back(
    target: &Target,
    changes: &[Change],
    unit: u8,
    baud: u32,
    profile: &Arc<Profile>,
) -> Result<(u8, u32), CommissionError> {
    let mut last = None;
    for (u, b) in answers_at(changes, unit, baud) {
        let mut link = target.open(b)?;
        match current_words(&mut link, target, u, changes, profile.answer_timeout).await {
            Ok(words) => {
                for (c, w) in changes.iter().zip(&words) {
                    let got = c.setting.field(*w);
                    if got != c.field {
                        return Err(CommissionError::Failed(format!(
                            "{} reads back {} instead of {}",
                            c.label,
                            c.setting.describe(got),
                            c.setting.describe(c.field)
                        )));
                    }
                }
                return Ok((u, b));
            }
            Err(e) => last = Some(e),
        }
    }
    Err(last.unwrap_or_else(|| CommissionError::Failed("nothing to read back".into())))
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profiles;

    fn wanted(setting: &str, channel: Option<&str>, value: &str) -> Wanted {
        Wanted {
            setting: setting.into(),
            channel: channel.map(str::to_string),
            value: value.into(),
        }
    }

    #[test]
    fn a_new_unit_and_baud_write_the_baud_first_and_the_address_last() {
        let p = Profiles::builtin().get("yl67").unwrap();
        let ch = p.channels(&[0, 0, 0, 0]).unwrap();
        let plan = plan_changes(
            &p,
            &ch,
            &[
                wanted("unit", None, "7"),
                wanted("baud", None, "19200"),
                wanted("ppr", Some("enc1"), "360"),
            ],
        )
        .unwrap();
        let regs: Vec<(u16, u16)> = plan.iter().map(|c| (c.register, c.field)).collect();
        // 40074 (enc1 pulses/rev) = 360, 40202 = 7 (19200), 40201 = 7.
        assert_eq!(regs, [(73, 360), (201, 7), (200, 7)]);
    }

    #[test]
    fn a_restart_applied_address_is_read_back_at_the_old_unit() {
        let p = Profiles::builtin().get("wj157").unwrap();
        let plan = plan_changes(
            &p,
            &[],
            &[wanted("unit", None, "12"), wanted("baud", None, "19200")],
        )
        .unwrap();
        assert_eq!(answers_at(&plan, 1, 9600), [(1, 9600)]);
        assert!(explain(&plan[1], 1).contains("unit 12 after its next power-up"));
    }

    #[test]
    fn a_zh_yx1600_address_applies_at_once_and_its_baud_may_or_may_not() {
        let p = Profiles::builtin().get("zh-yx1600").unwrap();
        let plan = plan_changes(
            &p,
            &[],
            &[wanted("unit", None, "2"), wanted("baud", None, "19200")],
        )
        .unwrap();
        assert_eq!(answers_at(&plan, 1, 9600), [(2, 9600), (2, 19200)]);
    }

    #[test]
    fn power_on_state_goes_to_all_sixteen_mode_words() {
        let p = Profiles::builtin().get("zh-yx1600").unwrap();
        let plan = plan_changes(&p, &[], &[wanted("power_on", None, "up")]).unwrap();
        assert_eq!(plan.len(), 16);
        assert_eq!((plan[15].register, plan[15].field), (0x070F, 1));
        assert_eq!(plan[2].label, "power_on #3");
    }

    #[test]
    fn bad_requests_are_refused_with_their_cause() {
        let p = Profiles::builtin().get("yl67").unwrap();
        let ch = p.channels(&[0, 0, 0, 0]).unwrap();
        let err = |w: Wanted| plan_changes(&p, &ch, &[w]).unwrap_err().to_string();
        assert!(err(wanted("power_on", None, "up")).contains("no setting \"power_on\""));
        assert!(err(wanted("unit", None, "0")).contains("1..=247"));
        assert!(err(wanted("baud", None, "1200")).contains("not one of"));
        assert!(err(wanted("ppr", Some("a0"), "100")).contains("no channel a0"));
        assert!(err(wanted("ppr", None, "100")).contains("per channel"));
        assert!(err(wanted("ppr", Some("enc0"), "0")).contains("1..=65535"));
    }
}

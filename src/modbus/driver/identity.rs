//! The module's identity: at discovery and after every reset the gateway reads the profile's
//! identification registers (data in the profile, not code). A module that says it is another
//! model is taken out of service (`wrong_model`), named by what it said and which model(s) that
//! means; a module that refuses the read is accepted with one warning.

use std::sync::Arc;

use tokio_modbus::ExceptionCode;

use crate::profile::{Profile, Profiles};

/// The identification of one known model.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Identity {
    /// Model name with its aliases, e.g. "yl67 (ibf67)".
    pub model: String,
    pub address: u16,
    pub words: Vec<u16>,
}

/// Identities of every known model: the built-in profiles, replaced or joined by `configured`
/// (user profiles of the bus's devices).
pub fn known(configured: &[Arc<Profile>]) -> Arc<[Identity]> {
    let builtin = Profiles::builtin();
    let mut profiles: Vec<Arc<Profile>> = builtin
        .names()
        .into_iter()
        .filter_map(|n| builtin.get(n))
        .chain(configured.iter().cloned())
        .collect();
    // One entry per model; a configured profile replaces the built-in one of that name.
    profiles.reverse();
    let mut seen = std::collections::BTreeSet::new();
    profiles.retain(|p| seen.insert(p.model.clone()));
    profiles.reverse();
    profiles
        .iter()
        .filter_map(|p| {
            let (address, words) = p.identify.clone()?;
            let model = if p.aliases.is_empty() {
                p.model.clone()
            } else {
                format!("{} ({})", p.model, p.aliases.join(", "))
            };
            Some(Identity {
                model,
                address,
                words,
            })
        })
        .collect()
}

/// What the identity check found.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Verdict {
    /// The module is the configured model (or the profile has no identification).
    Confirmed,
    /// The module refused its identification registers and matches no other model.
    Unidentified,
    /// The module is another model.
    Wrong(String),
}

/// Judges what the module answered. `own`: the answer at the configured model's registers;
/// `others`: the models whose identification the module answered exactly.
pub fn judge(
    configured: &str,
    expected: &(u16, Vec<u16>),
    own: &Result<Vec<u16>, ExceptionCode>,
    others: &[&Identity],
) -> Verdict {
    let means = if others.is_empty() {
        "no model the gateway knows".to_string()
    } else {
        others
            .iter()
            .map(|i| i.model.as_str())
            .collect::<Vec<_>>()
            .join(" or ")
    };
    match own {
        Ok(words) if *words == expected.1 => Verdict::Confirmed,
        Ok(words) => Verdict::Wrong(format!(
            "configured as {configured}, but the module says {} at register {} (expected {}): that is {means}",
            hex(words),
            expected.0,
            hex(&expected.1)
        )),
        Err(_) if others.is_empty() => Verdict::Unidentified,
        Err(e) => Verdict::Wrong(format!(
            "configured as {configured}, but the module refuses register {} ({e:?}) and identifies as {means}",
            expected.0
        )),
    }
}

fn hex(words: &[u16]) -> String {
    let w: Vec<String> = words.iter().map(|w| format!("{w:#06x}")).collect();
    format!("[{}]", w.join(", "))
}

#[cfg(test)]
mod tests {
    use super::*;

    fn id(model: &str) -> Identity {
        known(&[])
            .iter()
            .find(|i| i.model.starts_with(model))
            .unwrap()
            .clone()
    }

    #[test]
    fn the_seed_models_identify_as_their_datasheets_say() {
        assert_eq!(
            (id("yl67").address, id("yl67").words.clone()),
            (210, vec![0x0067])
        );
        assert_eq!(id("yl67").model, "yl67 (ibf67)");
        assert_eq!(
            (id("wj157").address, id("wj157").words.clone()),
            (210, vec![0x0150])
        );
        let zh = id("zh-yx1600");
        assert_eq!(
            (zh.address, zh.words),
            (0x0055, vec![0x5958, 0x3136, 0x3030])
        );
    }

    #[test]
    fn a_yl67_configured_as_wj157_is_the_wrong_model_and_named() {
        let yl = id("yl67");
        let v = judge("wj157", &(210, vec![0x0150]), &Ok(vec![0x0067]), &[&yl]);
        let Verdict::Wrong(msg) = v else {
            panic!("{v:?}")
        };
        assert!(
            msg.contains("0x0067") && msg.contains("yl67 (ibf67)"),
            "{msg}"
        );
    }

    #[test]
    fn a_module_refusing_the_registers_but_answering_another_models_is_the_wrong_model() {
        let zh = id("zh-yx1600");
        let v = judge(
            "yl67",
            &(210, vec![0x0067]),
            &Err(ExceptionCode::IllegalDataAddress),
            &[&zh],
        );
        assert!(matches!(v, Verdict::Wrong(m) if m.contains("zh-yx1600")));
    }

    #[test]
    fn a_module_that_cannot_be_identified_is_accepted() {
        let v = judge(
            "yl67",
            &(210, vec![0x0067]),
            &Err(ExceptionCode::IllegalDataAddress),
            &[],
        );
        assert_eq!(v, Verdict::Unidentified);
        assert_eq!(
            judge("yl67", &(210, vec![0x0067]), &Ok(vec![0x0067]), &[]),
            Verdict::Confirmed
        );
    }
}

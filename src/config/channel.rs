//! `[buses.<bus>.devices.<device>.channels.<name>]`: per-channel settings, keyed by the channel's
//! name (a map, so an environment variable can address one channel).

use super::walk::{Errors, Table, join};
use crate::profile::Profile;

/// What the gateway does with a ZH-YX1600 counter it finds stopped (command register 0, after
/// power-up or someone else's stop).
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, serde::Deserialize)]
#[serde(rename_all = "lowercase")]
pub enum Run {
    /// Start it counting up (the default: a stopped counter loses the plant's pulses).
    #[default]
    Up,
    /// Start it counting down.
    Down,
    /// Leave it as it is: another system starts and stops the counters.
    Leave,
}

/// `[buses.<bus>.devices.<device>.channels.<name>]`
#[derive(Debug, Clone, PartialEq)]
pub struct ChannelConfig {
    /// Pulses per revolution where the module has no register for it.
    pub ppr: Option<f64>,
    /// Highest plausible input rate; overrides the profile's.
    pub max_rate_hz: Option<f64>,
    /// Run state a stopped counter is put in, where the module starts and stops by register.
    pub run: Run,
    /// `false`: not polled or published; its saved state is kept.
    pub enabled: bool,
    /// Set the module's power-on state (ZH-YX1600 mode word pAuto bits) to `run`, once, so the
    /// counter counts by itself after a power cut; the module applies it after a restart.
    pub power_on: bool,
    /// A counter found paused (ZH-YX1600 0x0001) is resumed in the `run` direction; by default
    /// a pause set by someone is left alone.
    pub resume_paused: bool,
}

impl Default for ChannelConfig {
    fn default() -> ChannelConfig {
        ChannelConfig {
            ppr: None,
            max_rate_hz: None,
            run: Run::Up,
            enabled: true,
            power_on: false,
            resume_paused: false,
        }
    }
}

/// Checks one channel table of a device of `profile` (when the model is known).
pub(super) fn channel(
    mut ct: Table<'_>,
    cname: &str,
    profile: Option<&Profile>,
    errs: &mut Errors,
) -> ChannelConfig {
    let cpath = ct.path.clone();
    if let Some(p) = profile
        && !p.all_channels().iter().any(|c| c.name == cname)
    {
        errs.push(
            &cpath,
            ct.origin(),
            format!("model {} has no channel {cname}", p.model),
        );
    }
    let ppr = ct.opt::<f64>("ppr", errs);
    let max_rate_hz = ct.opt::<f64>("max_rate_hz", errs);
    for (key, v) in [("ppr", ppr), ("max_rate_hz", max_rate_hz)] {
        if v.is_some_and(|v| !(v > 0.0 && v.is_finite())) {
            errs.push(
                &join(&cpath, key),
                ct.origin(),
                "must be a number greater than zero",
            );
        }
    }
    let run = ct.opt::<Run>("run", errs).unwrap_or_default();
    let enabled = ct.opt::<bool>("enabled", errs).unwrap_or(true);
    let power_on = ct.opt::<bool>("power_on", errs).unwrap_or(false);
    let resume_paused = ct.opt::<bool>("resume_paused", errs).unwrap_or(false);
    if resume_paused && run == Run::Leave {
        errs.push(
            &join(&cpath, "resume_paused"),
            ct.origin(),
            "needs run = \"up\" or \"down\" (a paused counter is resumed in the run direction)",
        );
    }
    if power_on && run == Run::Leave {
        errs.push(
            &join(&cpath, "power_on"),
            ct.origin(),
            "needs run = \"up\" or \"down\" (the power-on state is set to the run direction)",
        );
    }
    if power_on
        && let Some(p) = profile
        && !p
            .all_channels()
            .iter()
            .any(|c| c.name == cname && c.power_on.is_some())
    {
        errs.push(
            &join(&cpath, "power_on"),
            ct.origin(),
            format!("model {} has no power-on state to set", p.model),
        );
    }
    ct.finish(errs);
    ChannelConfig {
        ppr,
        max_rate_hz,
        run,
        enabled,
        power_on,
        resume_paused,
    }
}

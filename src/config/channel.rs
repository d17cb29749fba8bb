//! `[buses.<bus>.devices.<device>.channels.<name>]`: per-channel settings, keyed by the channel's
//! name (a map, so an environment variable can address one channel): run state and presence,
//! engineering units (pulse weight, units of the total and the rate, Home Assistant device
//! class), publish policy.

use config::ValueKind;

use super::walk::{Errors, Table, join};
use crate::config::policy::PolicyOverride;
use crate::config::units::{ChannelUnits, RatePer, device_class_accepts};
use crate::decimal::Decimal;
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
    /// Engineering units: scale, unit, rate unit and time base, device class.
    pub units: ChannelUnits,
    /// Publish policy keys of this channel (over the device's).
    pub publish: PolicyOverride,
    /// `intervals` of this channel, when it overrides its device's.
    pub intervals: Option<Vec<crate::metering::Period>>,
    /// An M-Bus meter's record this channel names (its 0-based index in the answer).
    pub record: Option<usize>,
    /// `register = N`: the first address of this channel's block in a Modbus server output's
    /// map, pinned (otherwise the map places it; see `modbus::server::map`).
    pub register: Option<u16>,
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
            units: ChannelUnits::default(),
            publish: PolicyOverride::default(),
            intervals: None,
            record: None,
            register: None,
        }
    }
}

/// Checks one channel table of a device of `profile` (when the model is known).
pub(crate) fn channel(
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
    let enabled = ct.opt::<bool>("enabled", errs).unwrap_or(true);
    let (run, power_on, resume_paused) = run_keys(&mut ct, cname, profile, errs);
    let units = units(&mut ct, errs);
    let publish = super::publish::policy(&mut ct, errs);
    let intervals = super::metering::intervals(&mut ct, errs);
    let register = ct.int::<u16>("register", errs);
    ct.finish(errs);
    ChannelConfig {
        ppr,
        max_rate_hz,
        run,
        enabled,
        power_on,
        resume_paused,
        units,
        publish,
        intervals,
        record: None,
        register,
    }
}

/// `run`, `power_on` and `resume_paused`, which only make sense together.
fn run_keys(
    ct: &mut Table<'_>,
    cname: &str,
    profile: Option<&Profile>,
    errs: &mut Errors,
) -> (Run, bool, bool) {
    let cpath = ct.path.clone();
    let run = ct.opt::<Run>("run", errs).unwrap_or_default();
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
    (run, power_on, resume_paused)
}

/// Reads the unit keys of one channel table; every problem goes to `errs`.
pub(crate) fn units(t: &mut Table<'_>, errs: &mut Errors) -> ChannelUnits {
    let scale = scale(t, errs);
    let unit = text(t, "unit", errs);
    let rate_unit = text(t, "rate_unit", errs);
    let rate_per = match t.opt::<String>("rate_per", errs).as_deref() {
        None | Some("s") => RatePer::Second,
        Some("min") => RatePer::Minute,
        Some("h") => RatePer::Hour,
        Some(other) => {
            errs.push(
                &join(&t.path, "rate_per"),
                t.origin(),
                format!("{other:?} is not \"s\", \"min\" or \"h\""),
            );
            RatePer::Second
        }
    };
    let device_class = text(t, "device_class", errs);
    if let Some(class) = &device_class {
        match device_class_accepts(class, unit.as_deref()) {
            Ok(()) => {}
            Err(message) => errs.push(&join(&t.path, "device_class"), t.origin(), message),
        }
    }
    let obis = t.opt::<String>("obis", errs).and_then(|text| {
        text.parse()
            .map_err(|e| errs.push(&join(&t.path, "obis"), t.origin(), e))
            .ok()
    });
    for key in ["unit", "rate_unit", "rate_per", "device_class"] {
        if !t.has("scale") && t.has(key) {
            errs.push(
                &join(&t.path, key),
                t.origin(),
                "needs `scale` (units per pulse) on the same channel",
            );
        }
    }
    ChannelUnits {
        scale,
        unit,
        rate_unit,
        rate_per,
        device_class,
        obis,
    }
}

/// `scale`: a TOML number (`0.001`, `10`) or a string (`"0.001"`, what an environment override
/// gives), greater than zero, read as an exact decimal.
fn scale(t: &mut Table<'_>, errs: &mut Errors) -> Option<Decimal> {
    let value = t.raw("scale")?;
    let path = join(&t.path, "scale");
    let parsed = match &value.kind {
        ValueKind::Float(f) => Decimal::from_f64(*f),
        ValueKind::I64(n) => Decimal::parse(&n.to_string()),
        ValueKind::U64(n) => Decimal::parse(&n.to_string()),
        ValueKind::String(s) => Decimal::parse(s),
        _ => {
            errs.push(&path, value.origin(), "expected a number such as 0.001");
            return None;
        }
    };
    match parsed {
        Ok(d) if d.is_positive() => Some(d),
        Ok(_) => {
            errs.push(&path, value.origin(), "must be greater than zero");
            None
        }
        Err(e) => {
            errs.push(&path, value.origin(), e.to_string());
            None
        }
    }
}

/// A short label (a unit or a class name): not empty, no control characters.
fn text(t: &mut Table<'_>, key: &str, errs: &mut Errors) -> Option<String> {
    let v = t.opt::<String>(key, errs)?;
    if v.trim().is_empty() || v.len() > 32 || v.chars().any(char::is_control) {
        errs.push(
            &join(&t.path, key),
            t.origin(),
            "must be 1 to 32 printable characters",
        );
        return None;
    }
    Some(v)
}

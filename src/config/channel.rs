//! `[buses.B.devices.D.channels.C]`: engineering units of a channel (pulse weight, units of the
//! total and the rate, Home Assistant device class).

use config::ValueKind;

use super::walk::{Errors, Table, join};
use crate::publish::decimal::Decimal;
use crate::publish::units::{RatePer, device_class_accepts};

/// A channel's engineering units. Without `scale`, readings carry raw pulses only.
#[derive(Debug, Clone, Default, PartialEq)]
pub struct ChannelUnits {
    /// Units per pulse (0.001 for 1000 imp/kWh), exact as written.
    pub scale: Option<Decimal>,
    /// Unit of the scaled total (kWh, m³, L, mm…).
    pub unit: Option<String>,
    /// Unit of the scaled rate (kW, L/min…).
    pub rate_unit: Option<String>,
    /// The time base of the rate: per second, minute or hour.
    pub rate_per: RatePer,
    /// Home Assistant's device class of the total (energy, water, gas, volume, distance…).
    pub device_class: Option<String>,
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

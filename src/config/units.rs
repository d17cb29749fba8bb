//! Engineering units of a reading: the scaled total (`value`) and the scaled rate (`rate`), and
//! which Home Assistant device classes fit which units. Pure.

use crate::decimal::Decimal;

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
    /// `obis`: the OBIS name of the channel's total (`1-0:1.8.0`), in its readings and records.
    pub obis: Option<crate::metering::obis::Obis>,
}

/// The time base of a rate: pulses per second × scale × this many seconds.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq)]
pub enum RatePer {
    #[default]
    Second,
    Minute,
    Hour,
}

impl RatePer {
    pub fn seconds(self) -> u32 {
        match self {
            RatePer::Second => 1,
            RatePer::Minute => 60,
            RatePer::Hour => 3600,
        }
    }
}

/// The scaled total: `total × scale`, exact decimal text.
pub fn value(units: &ChannelUnits, total: i64) -> Option<Decimal> {
    units.scale.map(|s| s.times(total))
}

/// The scaled rate: pulses per second × scale × seconds of the time base, to 6 significant
/// digits (a rate is a measurement: more digits would only print float noise).
pub fn rate(units: &ChannelUnits, rate_hz: f64) -> Option<f64> {
    let scale = units.scale?;
    let v = rate_hz * scale.to_f64() * f64::from(units.rate_per.seconds());
    Some(significant(v, 6))
}

/// `v` rounded to `digits` significant digits, through decimal text so it prints short.
fn significant(v: f64, digits: usize) -> f64 {
    if v == 0.0 || !v.is_finite() {
        return v;
    }
    format!("{v:.*e}", digits - 1).parse().unwrap_or(v)
}

/// Units Home Assistant accepts per device class of a total (its sensor documentation's
/// device-class table). A class missing here is passed through unchecked.
const TOTAL_CLASSES: &[(&str, &[&str])] = &[
    (
        "energy",
        &[
            "J", "kJ", "MJ", "GJ", "mWh", "Wh", "kWh", "MWh", "GWh", "TWh", "cal", "kcal", "Mcal",
            "Gcal",
        ],
    ),
    ("water", &["L", "gal", "m³", "ft³", "CCF", "MCF"]),
    ("gas", &["L", "m³", "ft³", "CCF", "MCF"]),
    (
        "volume",
        &["L", "mL", "gal", "fl. oz.", "m³", "ft³", "CCF", "MCF"],
    ),
    (
        "distance",
        &["km", "m", "cm", "mm", "mi", "nmi", "yd", "in", "ft"],
    ),
    ("weight", &["kg", "g", "mg", "µg", "oz", "lb", "st"]),
];

/// Device classes of rates, and their units, by the device class of the total.
const RATE_CLASSES: &[(&str, &str, &[&str])] = &[
    (
        "energy",
        "power",
        &["mW", "W", "kW", "MW", "GW", "TW", "BTU/h"],
    ),
    (
        "water",
        "volume_flow_rate",
        &[
            "m³/h", "m³/min", "m³/s", "ft³/min", "L/h", "L/min", "L/s", "gal/h", "gal/min", "mL/s",
        ],
    ),
    (
        "gas",
        "volume_flow_rate",
        &[
            "m³/h", "m³/min", "m³/s", "ft³/min", "L/h", "L/min", "L/s", "gal/h", "gal/min", "mL/s",
        ],
    ),
    (
        "volume",
        "volume_flow_rate",
        &[
            "m³/h", "m³/min", "m³/s", "ft³/min", "L/h", "L/min", "L/s", "gal/h", "gal/min", "mL/s",
        ],
    ),
    (
        "distance",
        "speed",
        &[
            "mm/s", "mm/h", "mm/d", "m/s", "km/h", "ft/s", "in/s", "in/h", "in/d", "mph", "kn",
        ],
    ),
];

/// Whether Home Assistant takes `class` for a total in `unit`; the error says what it takes.
pub fn device_class_accepts(class: &str, unit: Option<&str>) -> Result<(), String> {
    let Some((_, units)) = TOTAL_CLASSES.iter().find(|(c, _)| *c == class) else {
        let known: Vec<&str> = TOTAL_CLASSES.iter().map(|(c, _)| *c).collect();
        return Err(format!(
            "{class:?} is not a device class for a total; use one of {}",
            known.join(", ")
        ));
    };
    match unit {
        Some(u) if units.contains(&u) => Ok(()),
        Some(u) => Err(format!(
            "device class {class} does not take unit {u:?}; it takes {}",
            units.join(", ")
        )),
        None => Err(format!(
            "device class {class} needs `unit` (one of {})",
            units.join(", ")
        )),
    }
}

/// The device class of a channel's rate, when its total's class has one for `rate_unit`.
pub fn rate_device_class(units: &ChannelUnits) -> Option<&'static str> {
    let class = units.device_class.as_deref()?;
    let rate_unit = units.rate_unit.as_deref()?;
    RATE_CLASSES
        .iter()
        .find(|(c, _, units)| *c == class && units.contains(&rate_unit))
        .map(|(_, rate_class, _)| *rate_class)
}

#[cfg(test)]
mod tests {
    use super::*;

    fn units(scale: &str, per: RatePer) -> ChannelUnits {
        ChannelUnits {
            scale: Some(Decimal::parse(scale).unwrap()),
            unit: Some("kWh".into()),
            rate_unit: Some("kW".into()),
            rate_per: per,
            device_class: Some("energy".into()),
            obis: None,
        }
    }

    #[test]
    fn a_thousand_pulses_per_kwh_at_one_pulse_per_second_is_3_6_kw() {
        let u = units("0.001", RatePer::Hour);
        assert_eq!(rate(&u, 1.0), Some(3.6));
        assert_eq!(value(&u, 1_234_567).unwrap().to_string(), "1234.567");
    }

    #[test]
    fn ten_litres_per_pulse_per_minute() {
        let u = ChannelUnits {
            rate_per: RatePer::Minute,
            ..units("10", RatePer::Minute)
        };
        assert_eq!(rate(&u, 0.5), Some(300.0));
    }

    #[test]
    fn a_rate_prints_without_float_noise() {
        let u = units("0.1", RatePer::Second);
        assert_eq!(rate(&u, 3.0).unwrap().to_string(), "0.3");
    }

    #[test]
    fn without_a_scale_there_is_no_value_or_rate() {
        let u = ChannelUnits::default();
        assert_eq!(value(&u, 5), None);
        assert_eq!(rate(&u, 5.0), None);
    }

    #[test]
    fn device_classes_take_only_their_units() {
        assert!(device_class_accepts("energy", Some("kWh")).is_ok());
        assert!(device_class_accepts("water", Some("m³")).is_ok());
        let e = device_class_accepts("energy", Some("m³")).unwrap_err();
        assert!(e.contains("kWh"), "{e}");
        assert!(device_class_accepts("energy", None).is_err());
        assert!(device_class_accepts("frequency", Some("rpm")).is_err());
    }

    #[test]
    fn a_rate_gets_the_class_that_matches_its_unit() {
        assert_eq!(
            rate_device_class(&units("0.001", RatePer::Hour)),
            Some("power")
        );
        let mut u = units("10", RatePer::Minute);
        u.device_class = Some("water".into());
        u.unit = Some("L".into());
        u.rate_unit = Some("L/min".into());
        assert_eq!(rate_device_class(&u), Some("volume_flow_rate"));
        u.rate_unit = Some("pulses/min".into());
        assert_eq!(rate_device_class(&u), None);
    }
}

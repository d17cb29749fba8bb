//! What a record's VIF and VIFEs mean together: the base from the VIF tables, then the
//! combinable (orthogonal) VIFEs of EN 13757-3, which scale the value, change its unit ("per
//! hour", "per input pulse"), make it a limit, a count of limit exceeds, a duration or a date,
//! or mark a record error. A VIFE this decoder does not know is kept and said, never guessed.
//! Pure.

use super::quantity::{Quantity, Unit};
use super::vif::Vib;
use super::vif_table::{self, Base};

/// A combinable VIFE that changes what the value is.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum Modifier {
    /// Per time, per pulse, per unit: (unit symbol, name part).
    Per(&'static str, &'static str),
    /// Multiplied by: (unit symbol, name part).
    Times(&'static str, &'static str),
    /// The date (and time) at which the quantity's accumulation started.
    StartOf,
    /// The VIF's unit without temperature correction.
    Uncorrected,
    /// Accumulated only where contributions are positive.
    PositiveOnly,
    /// The absolute value accumulated only where contributions are negative.
    NegativeOnly,
    /// A lower (`upper: false`) or upper limit value.
    Limit { upper: bool },
    /// The number of times the limit was exceeded.
    LimitExceeds { upper: bool },
    /// The date (/time) of the begin or end of the first or last limit exceed.
    LimitTime { upper: bool, last: bool, end: bool },
    /// How long the first or last limit exceed lasted.
    LimitDuration { upper: bool, last: bool },
    /// How long the first or last (something) lasted.
    Duration { last: bool },
    /// The value during a lower or upper limit exceed.
    DuringLimit { upper: bool },
    /// The date (/time) of the begin or end of the first or last (something).
    TimeOf { last: bool, end: bool },
    /// A value the meter expects (future value).
    Future,
}

impl Modifier {
    /// The part this adds to a channel name (`_per_hour`, `_upper_limit_exceeds`).
    pub fn suffix(&self) -> String {
        let ul = |upper: bool| if upper { "upper" } else { "lower" };
        let fl = |last: bool| if last { "last" } else { "first" };
        let be = |end: bool| if end { "end" } else { "begin" };
        match *self {
            Modifier::Per(_, name) => format!("_per_{name}"),
            Modifier::Times(_, name) => format!("_times_{name}"),
            Modifier::StartOf => "_start_date".into(),
            Modifier::Uncorrected => "_uncorrected".into(),
            Modifier::PositiveOnly => "_positive".into(),
            Modifier::NegativeOnly => "_negative".into(),
            Modifier::Limit { upper } => format!("_{}_limit", ul(upper)),
            Modifier::LimitExceeds { upper } => format!("_{}_limit_exceeds", ul(upper)),
            Modifier::LimitTime { upper, last, end } => {
                format!("_{}_limit_{}_{}_date", ul(upper), fl(last), be(end))
            }
            Modifier::LimitDuration { upper, last } => {
                format!("_{}_limit_{}_duration", ul(upper), fl(last))
            }
            Modifier::Duration { last } => format!("_{}_duration", fl(last)),
            Modifier::DuringLimit { upper } => format!("_during_{}_limit", ul(upper)),
            Modifier::TimeOf { last, end } => format!("_{}_{}_date", fl(last), be(end)),
            Modifier::Future => "_future".into(),
        }
    }

    /// Whether the record stays a running total of its quantity with this modifier.
    pub fn keeps_register(&self) -> bool {
        matches!(
            self,
            Modifier::Uncorrected | Modifier::PositiveOnly | Modifier::NegativeOnly
        )
    }
}

/// A record's meaning: quantity, unit and exponent after every VIFE, what the VIFEs changed,
/// and what could not be understood.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Meaning {
    pub quantity: Quantity,
    /// `None` for dimensionless values, counts and dates.
    pub unit: Option<Unit>,
    /// The decimal exponent of the value (`raw × 10^exp` in `unit`).
    pub exp: i32,
    pub modifiers: Vec<Modifier>,
    /// The value is a date or date and time (by its VIF or a VIFE).
    pub time_point: bool,
    /// A record error code the meter set (combinable VIFE 0x00–0x1F).
    pub record_error: Option<u8>,
    /// VIFEs (as sent) this decoder does not understand: the record is what the VIF says, and
    /// these may change that; such a record is never counted.
    pub not_understood: Vec<u8>,
}

/// What `vib` means.
pub fn meaning(vib: &Vib) -> Meaning {
    let vif = vib.vif();
    let vifes = vib.vifes();
    let (base, rest) = match (vif, vifes.split_first()) {
        (0xFB, Some((code, rest))) => (vif_table::fb(*code), rest),
        (0xFD, Some((code, rest))) => (vif_table::fd(*code), rest),
        (0x7C | 0xFC, _) => {
            let text = vib.text.clone().unwrap_or_default();
            let base = Base {
                quantity: Quantity::PlainText(text.clone()),
                unit: Some(Unit::Text(text)),
                exp: 0,
            };
            (base, vifes)
        }
        _ => (vif_table::primary(vif), vifes),
    };
    let time_point = matches!(base.quantity, Quantity::Date | Quantity::DateTime)
        || base.quantity == Quantity::Extended("battery_change_date_time");
    let mut m = Meaning {
        quantity: base.quantity,
        unit: base.unit,
        exp: base.exp,
        modifiers: Vec::new(),
        time_point,
        record_error: None,
        not_understood: Vec::new(),
    };
    for (i, vife) in rest.iter().enumerate() {
        if !combine(&mut m, *vife) {
            m.not_understood.extend_from_slice(&rest[i..]);
            break;
        }
    }
    m
}

/// Applies one combinable VIFE; `false` where it is not understood (it and every VIFE after
/// it are then kept as not understood: after 0x7F they are the manufacturer's).
fn combine(m: &mut Meaning, vife: u8) -> bool {
    let code = vife & 0x7F;
    match code {
        0x00..=0x1F => m.record_error = Some(code),
        0x20..=0x35 => per(m, code),
        0x36 => times(m, "s", "second"),
        0x37 => times(m, "s/V", "second_per_volt"),
        0x38 => times(m, "s/A", "second_per_ampere"),
        0x39 => point(m, Modifier::StartOf),
        0x3A => m.modifiers.push(Modifier::Uncorrected),
        0x3B => m.modifiers.push(Modifier::PositiveOnly),
        0x3C => m.modifiers.push(Modifier::NegativeOnly),
        0x40..=0x4F => return limits(m, code),
        0x50..=0x5F => {
            let modifier = Modifier::LimitDuration {
                upper: code & 0x08 != 0,
                last: code & 0x04 != 0,
            };
            duration(m, modifier, code);
        }
        0x60..=0x67 => duration(
            m,
            Modifier::Duration {
                last: code & 0x04 != 0,
            },
            code,
        ),
        0x68 | 0x6C => m.modifiers.push(Modifier::DuringLimit {
            upper: code & 0x04 != 0,
        }),
        0x6A | 0x6B | 0x6E | 0x6F => point(
            m,
            Modifier::TimeOf {
                last: code & 0x04 != 0,
                end: code & 0x01 != 0,
            },
        ),
        0x70..=0x77 => m.exp += i32::from(code & 0x07) - 6,
        0x7D => m.exp += 3,
        0x7E => m.modifiers.push(Modifier::Future),
        // 0x3D–0x3F, 0x69, 0x6D reserved; 0x78–0x7B additive correction constants, 0x7C a
        // further table, 0x7F the manufacturer's: not understood here.
        _ => return false,
    }
    true
}

/// "Per" VIFEs 0x20–0x35: the unit becomes the VIF's unit per something.
fn per(m: &mut Meaning, code: u8) {
    const PER: [(&str, &str); 22] = [
        ("s", "second"),
        ("min", "minute"),
        ("h", "hour"),
        ("d", "day"),
        ("week", "week"),
        ("month", "month"),
        ("year", "year"),
        ("revolution", "revolution"),
        ("pulse (input 0)", "input_pulse_0"),
        ("pulse (input 1)", "input_pulse_1"),
        ("pulse (output 0)", "output_pulse_0"),
        ("pulse (output 1)", "output_pulse_1"),
        ("l", "litre"),
        ("m³", "m3"),
        ("kg", "kg"),
        ("K", "kelvin"),
        ("kWh", "kwh"),
        ("GJ", "gj"),
        ("kW", "kw"),
        ("K·l", "kelvin_litre"),
        ("V", "volt"),
        ("A", "ampere"),
    ];
    let (symbol, name) = PER[usize::from(code - 0x20)];
    m.modifiers.push(Modifier::Per(symbol, name));
    m.unit = m.unit.take().map(|u| Unit::Per(Box::new(u), symbol));
}

fn times(m: &mut Meaning, symbol: &'static str, name: &'static str) {
    m.modifiers.push(Modifier::Times(symbol, name));
    m.unit = m.unit.take().map(|u| Unit::Times(Box::new(u), symbol));
}

/// The value becomes a date (/time): it has no unit and no scale.
fn point(m: &mut Meaning, modifier: Modifier) {
    m.modifiers.push(modifier);
    m.unit = None;
    m.exp = 0;
    m.time_point = true;
}

/// The value becomes a duration in the VIFE's time unit (`nn`).
fn duration(m: &mut Meaning, modifier: Modifier, code: u8) {
    m.modifiers.push(modifier);
    m.unit = Some(Unit::time_nn(code));
    m.exp = 0;
}

/// VIFEs 0x40–0x4F: limit values, counts of limit exceeds, their dates.
fn limits(m: &mut Meaning, code: u8) -> bool {
    let upper = code & 0x08 != 0;
    match code & 0x07 {
        0 => m.modifiers.push(Modifier::Limit { upper }),
        1 => {
            m.modifiers.push(Modifier::LimitExceeds { upper });
            m.unit = None;
            m.exp = 0;
        }
        2 | 3 | 6 | 7 => point(
            m,
            Modifier::LimitTime {
                upper,
                last: code & 0x04 != 0,
                end: code & 0x01 != 0,
            },
        ),
        _ => return false,
    }
    true
}

#[cfg(test)]
mod tests {
    use super::*;

    fn of(bytes: &[u8]) -> Meaning {
        meaning(&Vib {
            bytes: bytes.to_vec(),
            text: None,
            text_before_vifes: false,
        })
    }

    #[test]
    fn a_duration_of_limit_exceed_is_seconds_not_a_volume_flow() {
        // BE 50: volume flow (m³/h), duration of the first lower limit exceed, in seconds.
        let m = of(&[0xBE, 0x50]);
        assert_eq!(m.quantity, Quantity::VolumeFlow);
        assert_eq!(m.unit, Some(Unit::Second));
        assert_eq!(
            m.modifiers,
            [Modifier::LimitDuration {
                upper: false,
                last: false
            }]
        );
    }

    #[test]
    fn a_per_pulse_vife_makes_a_pulse_weight() {
        let m = of(&[0x90, 0x28]);
        assert_eq!(m.unit.unwrap().symbol(), "m³/pulse (input 0)");
        assert_eq!(m.exp, -6);
    }

    #[test]
    fn a_multiplicative_correction_moves_the_exponent() {
        assert_eq!(of(&[0x84, 0x74]).exp, 1 - 2);
        assert_eq!(of(&[0x84, 0x7D]).exp, 1 + 3);
    }

    #[test]
    fn vifes_after_the_manufacturer_escape_are_not_read_as_standard_ones() {
        // ABB: energy ×10 Wh, then FF (manufacturer) F2 00: F2 is not a correction here.
        let m = of(&[0x84, 0xFF, 0xF2, 0x00]);
        assert_eq!(m.exp, 1);
        assert_eq!(m.not_understood, [0xFF, 0xF2, 0x00]);
    }

    #[test]
    fn fd_and_fb_take_their_code_from_the_first_vife() {
        let volts = of(&[0xFD, 0x48]);
        assert_eq!((volts.unit, volts.exp), (Some(Unit::Volt), -1));
        assert_eq!(of(&[0xFB, 0x01]).exp, 6);
        let flags = of(&[0xFD, 0x97, 0x15]);
        assert_eq!(flags.record_error, Some(0x15));
    }
}

//! Demand as a rate: the largest demand record's pulses over its length, per hour, in the
//! rate unit of the channel's unit. Pure.
//!
//! A demand interval divides an hour (`check` says so), so pulses per hour are the record's
//! delta times a whole number and the rate stays an exact decimal: 15 minutes × 4.

use super::billing::Peak;
use crate::decimal::Decimal;

/// The rate unit of a counted unit: an energy (`Wh`, `kWh`, `MWh`, `varh`…) drops its hour
/// (Wh → W), anything else is per hour (m³ → m³/h); no unit counts pulses per hour.
pub fn rate_unit(unit: Option<&str>) -> String {
    match unit {
        None => "pulses/h".to_string(),
        Some(u) if u.ends_with("Wh") || u.ends_with("varh") => u[..u.len() - 1].to_string(),
        Some(u) => format!("{u}/h"),
    }
}

/// The peak's mean rate per hour: scaled when the channel has a scale, else in pulses.
pub fn rate(peak: &Peak, scale: Option<&Decimal>) -> Decimal {
    let per_hour = peak.delta * (3_600_000 / peak.ms.max(1));
    match scale {
        Some(s) => s.times(per_hour),
        None => Decimal::parse("1").expect("one").times(per_hour),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn peak(delta: i64, ms: i64) -> Peak {
        Peak {
            delta,
            start_ms: 0,
            ms,
        }
    }

    #[test]
    fn energy_demand_drops_the_hour_and_a_quarter_hour_counts_four_times() {
        assert_eq!(rate_unit(Some("kWh")), "kW");
        assert_eq!(rate_unit(Some("Wh")), "W");
        assert_eq!(rate_unit(Some("m³")), "m³/h");
        assert_eq!(rate_unit(None), "pulses/h");
        let scale = Decimal::parse("0.001").unwrap();
        // 1234 pulses of 1 Wh in 15 min: 1.234 kWh, 4.936 kW.
        let r = rate(&peak(1234, 900_000), Some(&scale));
        assert_eq!(r.to_string(), "4.936");
        assert_eq!(rate(&peak(7, 60_000), None).to_string(), "420");
    }
}

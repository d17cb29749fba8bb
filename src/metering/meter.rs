//! Meter readings: a channel's published `reading` is its scaled total plus an offset that
//! `set_reading` moves to the meter's display. The total, the deltas and the intervals never
//! move (Home Assistant's `total_increasing` sensor sees no jump); the reading sensor's
//! `last_reset` moves with the offset instead. Pure.

use serde::{Deserialize, Serialize};

use crate::publish::decimal::{Decimal, DecimalError};

/// The persisted offset of a channel's reading and when it was last set.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeterOffset {
    /// Exact decimal text, in the channel's unit.
    pub offset: String,
    /// When `set_reading` set it (Unix ms): the reading sensor's `last_reset`.
    pub since_ms: i64,
}

impl MeterOffset {
    /// The offset that makes `scale × total` read `display`, set at `now_ms`.
    pub fn to_show(display: &Decimal, scale: &Decimal, total: i64, now_ms: i64) -> MeterOffset {
        MeterOffset {
            offset: display.minus(&scale.times(total)).to_string(),
            since_ms: now_ms,
        }
    }

    /// The offset as a number (a state file edited by hand may not hold one).
    pub fn value(&self) -> Result<Decimal, DecimalError> {
        Decimal::parse(&self.offset)
    }
}

/// The published reading: `scale × total + offset` (no offset: the scaled total).
pub fn reading(scale: &Decimal, total: i64, offset: Option<&MeterOffset>) -> Decimal {
    let scaled = scale.times(total);
    match offset.and_then(|o| o.value().ok()) {
        Some(o) => scaled.plus(&o),
        None => scaled,
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn d(text: &str) -> Decimal {
        Decimal::parse(text).unwrap()
    }

    #[test]
    fn setting_a_reading_moves_the_reading_to_the_display_and_later_pulses_add_to_it() {
        let scale = d("0.001");
        let o = MeterOffset::to_show(&d("12345.678"), &scale, 2_000, 7);
        assert_eq!(o.offset, "12343.678");
        assert_eq!(o.since_ms, 7);
        assert_eq!(reading(&scale, 2_000, Some(&o)).to_string(), "12345.678");
        assert_eq!(reading(&scale, 2_500, Some(&o)).to_string(), "12346.178");
        assert_eq!(reading(&scale, 2_500, None).to_string(), "2.5");
    }

    #[test]
    fn a_display_below_the_scaled_total_gives_a_negative_offset() {
        let scale = d("0.5");
        let o = MeterOffset::to_show(&d("3"), &scale, 100, 0);
        assert_eq!(o.offset, "-47");
        assert_eq!(reading(&scale, 101, Some(&o)).to_string(), "3.5");
    }
}

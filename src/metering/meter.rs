//! Meter readings: a channel's published `reading` is its scaled total plus an offset that
//! `set_reading` moves to the meter's display. The total, the deltas and the intervals never
//! move (Home Assistant's `total_increasing` sensor sees no jump); the reading sensor's
//! `last_reset` moves with the offset instead. Pure.

use serde::{Deserialize, Serialize};

use crate::decimal::{Decimal, DecimalError};

/// The persisted offset of a channel's reading and when it was last set.
#[derive(Debug, Clone, PartialEq, Eq, Serialize, Deserialize)]
pub struct MeterOffset {
    /// Exact decimal text, in the channel's unit.
    pub offset: String,
    /// When `set_reading` set it (Unix ms): the reading sensor's `last_reset`.
    pub since_ms: i64,
}

impl MeterOffset {
    /// The offset that makes `scale × total` read `display`, set at `now_ms`; `None` when the
    /// display and the scale are too far apart in digits to add exactly.
    pub fn to_show(
        display: &Decimal,
        scale: &Decimal,
        total: i64,
        now_ms: i64,
    ) -> Option<MeterOffset> {
        let offset = display.minus(&scale.times(total))?;
        // It must add back: the published reading is this sum.
        scale.times(total).plus(&offset)?;
        Some(MeterOffset {
            offset: offset.to_string(),
            since_ms: now_ms,
        })
    }

    /// The offset as a number (a state file edited by hand may not hold one).
    pub fn value(&self) -> Result<Decimal, DecimalError> {
        Decimal::parse(&self.offset)
    }
}

/// The published reading: `scale × total + offset` (no offset: the scaled total); `None` if
/// the offset (from a state file edited by hand) is not a number or does not add.
pub fn reading(scale: &Decimal, total: i64, offset: Option<&MeterOffset>) -> Option<Decimal> {
    let scaled = scale.times(total);
    match offset {
        Some(o) => scaled.plus(&o.value().ok()?),
        None => Some(scaled),
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
        let o = MeterOffset::to_show(&d("12345.678"), &scale, 2_000, 7).unwrap();
        assert_eq!(o.offset, "12343.678");
        assert_eq!(o.since_ms, 7);
        assert_eq!(
            reading(&scale, 2_000, Some(&o)).unwrap().to_string(),
            "12345.678"
        );
        assert_eq!(
            reading(&scale, 2_500, Some(&o)).unwrap().to_string(),
            "12346.178"
        );
        assert_eq!(reading(&scale, 2_500, None).unwrap().to_string(), "2.5");
    }

    #[test]
    fn a_display_below_the_scaled_total_gives_a_negative_offset() {
        let scale = d("0.5");
        let o = MeterOffset::to_show(&d("3"), &scale, 100, 0).unwrap();
        assert_eq!(o.offset, "-47");
        assert_eq!(reading(&scale, 101, Some(&o)).unwrap().to_string(), "3.5");
    }

    #[test]
    fn a_display_that_cannot_be_added_exactly_is_refused_and_a_bad_saved_offset_gives_no_reading() {
        let tiny = d("0.000000000000000001e-18");
        assert_eq!(
            MeterOffset::to_show(&tiny, &d("999999999999999999"), 1, 0),
            None
        );
        let edited = MeterOffset {
            offset: "twelve".into(),
            since_ms: 0,
        };
        assert_eq!(reading(&d("0.001"), 5, Some(&edited)), None);
    }
}

use super::*;
use crate::metering::clock::iso;

fn at(text: &str) -> i64 {
    text.parse::<jiff::Timestamp>().unwrap().as_millisecond()
}

fn monthly(day: i8) -> BillingConfig {
    BillingConfig {
        cycle: Cycle::Monthly { day },
        demand: None,
        signing_key: None,
        signer: None,
    }
}

#[test]
fn a_monthly_period_closes_at_local_midnight_of_its_day_this_month_or_the_next() {
    let berlin = Clock::named("Europe/Berlin").unwrap();
    let b = monthly(15);
    // 3 March 2026 (CET): the 15th at 00:00 CET is 14 March 23:00Z.
    assert_eq!(
        iso(b.close_after(&berlin, at("2026-03-03T10:00:00Z"))),
        "2026-03-14T23:00:00Z"
    );
    // From that close, the next is 15 April at 00:00 CEST (22:00Z): a month across the change.
    assert_eq!(
        iso(b.close_after(&berlin, at("2026-03-14T23:00:00Z"))),
        "2026-04-14T22:00:00Z"
    );
    // December rolls into January.
    assert_eq!(
        iso(monthly(1).close_after(&Clock::default(), at("2026-12-05T00:00:00Z"))),
        "2027-01-01T00:00:00Z"
    );
}

#[test]
fn a_daily_period_on_the_spring_forward_day_lasts_23_hours() {
    let berlin = Clock::named("Europe/Berlin").unwrap();
    let b = BillingConfig {
        cycle: Cycle::Daily,
        demand: None,
        signing_key: None,
        signer: None,
    };
    let start = at("2026-03-28T23:00:00Z");
    assert_eq!(b.close_after(&berlin, start) - start, 23 * 3_600_000);
}

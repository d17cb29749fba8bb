use super::*;
use crate::metering::clock::iso;

fn at(text: &str) -> i64 {
    text.parse::<jiff::Timestamp>().unwrap().as_millisecond()
}

fn raw(tariff: &str, days: &[&str], from: &str, to: &str) -> RawRule {
    RawRule {
        tariff: tariff.into(),
        days: days.iter().map(|d| d.to_string()).collect(),
        from: from.into(),
        to: to.into(),
    }
}

const WEEKDAYS: [&str; 5] = ["mon", "tue", "wed", "thu", "fri"];

/// The calendar: peak on weekdays 07:00–21:00, Christmas off-peak.
fn peak_calendar() -> Calendar {
    Calendar::new(
        "offpeak",
        &["2026-12-25".into(), "2026-12-26".into()],
        &[raw("peak", &WEEKDAYS, "07:00", "21:00")],
    )
    .unwrap()
}

#[test]
fn a_friday_morning_is_offpeak_until_seven_local_and_peak_from_seven_exactly() {
    let cal = peak_calendar();
    let berlin = Clock::named("Europe/Berlin").unwrap();
    // Friday 4 December 2026, CET (UTC+1): 07:00 local is 06:00Z.
    assert_eq!(cal.at(&berlin, at("2026-12-04T05:59:59.999Z")), "offpeak");
    assert_eq!(cal.at(&berlin, at("2026-12-04T06:00:00Z")), "peak");
    assert_eq!(cal.at(&berlin, at("2026-12-04T19:59:59Z")), "peak");
    assert_eq!(
        cal.at(&berlin, at("2026-12-04T20:00:00Z")),
        "offpeak",
        "to is exclusive"
    );
    assert_eq!(
        iso(cal.next_switch(&berlin, at("2026-12-04T05:58:00Z"))),
        "2026-12-04T06:00:00Z"
    );
    let changes = cal.changes(&berlin, at("2026-12-04T05:58:00Z"), 3);
    let texts: Vec<(String, &str)> = changes.iter().map(|(t, n)| (iso(*t), *n)).collect();
    assert_eq!(
        texts,
        [
            ("2026-12-04T06:00:00Z".to_string(), "peak"),
            ("2026-12-04T20:00:00Z".to_string(), "offpeak"),
            // Saturday and Sunday take the default: the next peak is Monday's.
            ("2026-12-07T06:00:00Z".to_string(), "peak"),
        ]
    );
}

#[test]
fn a_holiday_takes_the_default_tariff_all_day_even_on_a_weekday() {
    let cal = peak_calendar();
    let berlin = Clock::named("Europe/Berlin").unwrap();
    // Friday 25 December 2026 at 10:00 local.
    assert_eq!(cal.at(&berlin, at("2026-12-25T09:00:00Z")), "offpeak");
    assert_eq!(cal.at(&berlin, at("2026-12-24T09:00:00Z")), "peak");
}

#[test]
fn the_berlin_spring_forward_night_switches_on_the_local_clock_on_both_sides() {
    // Sunday 29 March 2026: 02:00 CET jumps to 03:00 CEST (01:00Z).
    let cal = Calendar::new(
        "offpeak",
        &[],
        &[
            raw("night", &["sun"], "00:00", "03:00"),
            raw("peak", &["sun"], "03:00", "00:00"),
        ],
    )
    .unwrap();
    let berlin = Clock::named("Europe/Berlin").unwrap();
    assert_eq!(
        cal.at(&berlin, at("2026-03-29T00:59:00Z")),
        "night",
        "01:59 CET"
    );
    assert_eq!(
        cal.at(&berlin, at("2026-03-29T01:00:00Z")),
        "peak",
        "03:00 CEST"
    );
    assert_eq!(
        iso(cal.next_switch(&berlin, at("2026-03-29T00:59:00Z"))),
        "2026-03-29T01:00:00Z",
        "one hour after 00:00 CET, not two: the day has 23 hours"
    );
    // The day before and the day after, 03:00 local is 02:00Z and 01:00Z.
    assert_eq!(
        cal.at(&berlin, at("2026-03-28T02:00:00Z")),
        "offpeak",
        "Saturday"
    );
    assert_eq!(
        cal.at(&berlin, at("2026-03-29T21:59:59Z")),
        "peak",
        "23:59:59 CEST"
    );
    assert_eq!(
        cal.at(&berlin, at("2026-03-29T22:00:00Z")),
        "offpeak",
        "Monday"
    );
}

#[test]
fn a_rule_time_inside_the_spring_gap_switches_when_the_clock_jumps_over_it() {
    let cal = Calendar::new("offpeak", &[], &[raw("peak", &["sun"], "02:30", "00:00")]).unwrap();
    let berlin = Clock::named("Europe/Berlin").unwrap();
    assert_eq!(cal.at(&berlin, at("2026-03-29T00:59:59Z")), "offpeak");
    assert_eq!(cal.at(&berlin, at("2026-03-29T01:00:00Z")), "peak");
    assert_eq!(
        iso(cal.next_switch(&berlin, at("2026-03-29T00:30:00Z"))),
        "2026-03-29T01:00:00Z"
    );
}

#[test]
fn a_merged_span_names_every_tariff_it_crossed_in_order() {
    let cal = peak_calendar();
    let utc = Clock::default();
    let spanned = cal.spanned(&utc, at("2026-12-04T06:00:00Z"), at("2026-12-04T08:00:00Z"));
    assert_eq!(spanned, ["offpeak", "peak"]);
    let inside = cal.spanned(&utc, at("2026-12-04T07:00:00Z"), at("2026-12-04T07:15:00Z"));
    assert_eq!(inside, ["peak"]);
}

#[test]
fn tariffs_are_numbered_in_the_order_they_are_first_named_the_default_first() {
    let cal = Calendar::new(
        "offpeak",
        &[],
        &[
            raw("peak", &WEEKDAYS, "07:00", "21:00"),
            raw("shoulder", &["sat"], "07:00", "13:00"),
            raw("peak", &["sat"], "13:00", "15:00"),
        ],
    )
    .unwrap();
    assert_eq!(cal.names(), ["offpeak", "peak", "shoulder"]);
    assert_eq!(cal.number("shoulder"), Some(3));
    assert_eq!(cal.number("none"), None);
}

#[test]
fn rule_times_off_an_interval_grid_are_named() {
    let cal = Calendar::new("offpeak", &[], &[raw("peak", &WEEKDAYS, "07:10", "21:00")]).unwrap();
    assert_eq!(cal.off_grid(&Period::parse("15min").unwrap()), ["07:10"]);
    assert!(cal.off_grid(&Period::parse("5min").unwrap()).is_empty());
    assert_eq!(
        cal.off_grid(&Period::parse("1d").unwrap()),
        ["07:10", "21:00"]
    );
}

#[test]
fn unknown_days_bad_times_empty_and_shadowed_rules_are_refused_each_by_its_rule() {
    let errs = Calendar::new(
        "offpeak",
        &["2026-13-01".into()],
        &[
            raw("peak", &["monday", "tue", "tue"], "07:00", "21:00"),
            raw("peak", &["wed"], "22:00", "06:00"),
            raw("peak", &["thu"], "7:00", "24:00"),
            raw("peak", &[], "07:00", "08:00"),
            raw("peak", &WEEKDAYS, "07:00", "21:00"),
            raw("shoulder", &["fri"], "08:00", "09:00"),
            raw("bad name", &["sat"], "08:00", "09:00"),
        ],
    )
    .unwrap_err();
    let want = [
        (None, TariffError::Holiday("2026-13-01".into())),
        (Some(0), TariffError::Day("monday".into())),
        (Some(0), TariffError::DayTwice("tue".into())),
        (
            Some(1),
            TariffError::Empty {
                from: "22:00".into(),
                to: "06:00".into(),
            },
        ),
        (Some(2), TariffError::Time("7:00".into())),
        (Some(2), TariffError::Time("24:00".into())),
        (Some(3), TariffError::NoDays),
        (Some(5), TariffError::Shadowed),
    ];
    assert_eq!(errs, want);
}

#[test]
fn a_rule_partly_covered_by_an_earlier_one_still_applies_where_it_is_not() {
    let cal = Calendar::new(
        "offpeak",
        &[],
        &[
            raw("peak", &["mon"], "07:00", "12:00"),
            raw("shoulder", &["mon", "tue"], "07:00", "12:00"),
        ],
    )
    .unwrap();
    let utc = Clock::default();
    // Tuesday 8 December 2026, 08:00 UTC.
    assert_eq!(cal.at(&utc, at("2026-12-08T08:00:00Z")), "shoulder");
    assert_eq!(cal.at(&utc, at("2026-12-07T08:00:00Z")), "peak");
}

#[test]
fn check_describes_the_tariffs_and_the_next_switches_on_both_clocks() {
    let berlin = Clock::named("Europe/Berlin").unwrap();
    let text = describe(&peak_calendar(), &berlin, at("2026-12-04T05:58:00Z"), 2);
    assert_eq!(
        text,
        "tariffs (Europe/Berlin): 1 = offpeak, 2 = peak; now offpeak\n  \
         2026-12-04T06:00:00Z  Fri 2026-12-04 07:00 CET  -> peak\n  \
         2026-12-04T20:00:00Z  Fri 2026-12-04 21:00 CET  -> offpeak\n"
    );
}

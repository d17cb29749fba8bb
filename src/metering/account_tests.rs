use super::*;
use crate::metering::billing::{Cycle, PeriodStatus};
use crate::metering::interval::{IntervalState, Status};
use crate::metering::period::Period;
use crate::metering::tariff::RawRule;

fn at(text: &str) -> i64 {
    text.parse::<jiff::Timestamp>().unwrap().as_millisecond()
}

/// Peak on weekdays 07:00-21:00, off-peak otherwise.
fn calendar() -> Calendar {
    Calendar::new(
        "offpeak",
        &[],
        &[RawRule {
            tariff: "peak".into(),
            days: ["mon", "tue", "wed", "thu", "fri"]
                .map(String::from)
                .to_vec(),
            from: "07:00".into(),
            to: "21:00".into(),
        }],
    )
    .unwrap()
}

/// A channel metered on `periods`, read every `step_ms` with `rate(at)` pulses per read,
/// from `from` for `n` reads: the records with their bookings, and the account.
struct Channel {
    clock: Clock,
    calendar: Calendar,
    billing: Option<BillingConfig>,
    periods: Vec<Period>,
    states: Vec<IntervalState>,
    account: Account,
    total: i64,
    records: Vec<(Arc<str>, Record)>,
}

impl Channel {
    fn new(zone: &str, periods: &[&str], billing: Option<BillingConfig>) -> Channel {
        Channel {
            clock: Clock::named(zone).unwrap(),
            calendar: calendar(),
            billing,
            periods: periods.iter().map(|p| Period::parse(p).unwrap()).collect(),
            states: periods.iter().map(|_| IntervalState::default()).collect(),
            account: Account::default(),
            total: 0,
            records: Vec::new(),
        }
    }

    fn read(&mut self, at_ms: i64, pulses: i64) {
        self.total += pulses;
        let read = Read {
            at_ms,
            total: self.total,
            event: None,
        };
        let fresh = self.states[0].open.is_none();
        let mut closed = Vec::new();
        for (p, st) in self.periods.iter().zip(&mut self.states) {
            if let Some(r) = st.observe(&self.clock, p, read) {
                closed.push((Arc::from(p.text()), r));
            }
        }
        let books = Books {
            clock: &self.clock,
            calendar: Some(&self.calendar),
            billing: self.billing.as_ref(),
        };
        let opened = self.states[0]
            .open
            .as_ref()
            .map(|o| o.start_ms)
            .filter(|_| fresh);
        let shortest = Shortest {
            period: self.periods[0].text(),
            fresh,
            opened,
        };
        self.account.book(&books, &shortest, read, &mut closed);
        self.records.extend(closed);
    }

    fn run(&mut self, from: i64, step_ms: i64, n: i64, pulses: impl Fn(i64) -> i64) {
        for i in 0..n {
            let t = from + i * step_ms;
            self.read(t, pulses(t));
        }
    }

    fn tariff_sums(&self, period: &str) -> BTreeMap<String, i64> {
        let mut sums = BTreeMap::new();
        for (p, r) in &self.records {
            if &**p == period {
                let b = r.booking.as_ref().unwrap();
                *sums.entry(b.tariff.clone().unwrap()).or_default() += r.delta;
            }
        }
        sums
    }
}

#[test]
fn across_a_friday_morning_peak_rule_each_register_moves_by_exactly_its_records() {
    // Friday 4 December 2026 in Berlin: 07:00 local is 06:00Z.
    let mut ch = Channel::new("Europe/Berlin", &["15min", "1h"], None);
    ch.run(at("2026-12-04T05:00:20Z"), 60_000, 120, |t| 1 + t % 7);
    let tariffs: Vec<(String, String)> = ch
        .records
        .iter()
        .filter(|(p, _)| &**p == "15min")
        .map(|(_, r)| {
            let b = r.booking.as_ref().unwrap();
            (
                crate::metering::clock::iso(r.start_ms),
                b.tariff.clone().unwrap(),
            )
        })
        .collect();
    assert_eq!(
        tariffs[3],
        ("2026-12-04T05:45:00Z".into(), "offpeak".into())
    );
    assert_eq!(tariffs[4], ("2026-12-04T06:00:00Z".into(), "peak".into()));
    assert_eq!(ch.tariff_sums("15min"), ch.account.registers);
    // The last register published of each tariff is its sum so far.
    for name in ["offpeak", "peak"] {
        let last = ch
            .records
            .iter()
            .filter_map(|(_, r)| {
                r.booking
                    .as_ref()?
                    .register
                    .filter(|_| r.booking.as_ref().unwrap().tariff.as_deref() == Some(name))
            })
            .next_back()
            .unwrap();
        assert_eq!(last.total, ch.account.registers[name], "{name}");
    }
    // Hour records carry the tariff of their start and are not booked twice.
    let hours: Vec<&Record> = ch
        .records
        .iter()
        .filter(|(p, _)| &**p == "1h")
        .map(|(_, r)| r)
        .collect();
    assert!(
        hours
            .iter()
            .all(|r| r.booking.as_ref().unwrap().register.is_none())
    );
    let seqs: Vec<u64> = ch
        .records
        .iter()
        .filter_map(|(_, r)| Some(r.booking.as_ref()?.register?.seq))
        .collect();
    assert_eq!(
        seqs,
        (1..=seqs.len() as u64).collect::<Vec<_>>(),
        "one seq per publication"
    );
}

#[test]
fn a_merged_record_across_a_switch_is_booked_to_its_start_tariff_and_names_both() {
    let mut ch = Channel::new("UTC", &["15min"], None);
    ch.read(at("2026-12-04T06:30:01Z"), 0);
    ch.read(at("2026-12-04T06:45:01Z"), 10);
    // The gateway is away over 07:00 and 07:15.
    ch.read(at("2026-12-04T07:30:02Z"), 33);
    let (_, merged) = ch.records.last().unwrap();
    assert_eq!(merged.status, Status::Merged);
    let b = merged.booking.as_ref().unwrap();
    assert_eq!(b.tariff.as_deref(), Some("offpeak"));
    assert_eq!(b.tariffs, ["offpeak", "peak"]);
    assert_eq!(ch.account.registers["offpeak"], 43);
    assert_eq!(ch.account.registers.get("peak"), None);
}

fn daily(demand: &str) -> Option<BillingConfig> {
    Some(BillingConfig {
        cycle: Cycle::Daily,
        demand: Some(Period::parse(demand).unwrap()),
        signing_key: None,
        signer: None,
    })
}

#[test]
fn a_partial_first_day_books_its_pulses_before_the_first_boundary_and_sums_by_tariff_to_delta() {
    let mut ch = Channel::new("UTC", &["15min"], daily("15min"));
    // Friday from 06:52:30: three reads before the 07:00 boundary (off-peak), then peak.
    let start = at("2026-12-04T06:52:30Z");
    ch.run(start, 150_000, 24 * 24, |t| if t % 3 == 0 { 5 } else { 2 });
    let billing: Vec<&BillingRecord> = ch
        .records
        .iter()
        .flat_map(|(_, r)| &r.booking.as_ref().unwrap().billing)
        .collect();
    assert_eq!(billing.len(), 1, "one midnight in the run");
    let b = billing[0];
    assert_eq!(b.status, PeriodStatus::Partial);
    assert_eq!(b.start_ms, start, "from the first reading");
    assert_eq!(b.end_ms, at("2026-12-05T00:00:00Z"));
    assert_eq!(b.delta, b.total_end - b.total_start);
    assert_eq!(b.by_tariff.values().sum::<i64>(), b.delta);
    assert!(b.by_tariff["offpeak"] > 0 && b.by_tariff["peak"] > 0);
    assert_eq!(b.seq, 1);
    // The next period is whole and begins where this one ended.
    let open = ch.account.open.as_ref().unwrap();
    assert_eq!(
        (open.start_ms, open.total_start, open.partial),
        (b.end_ms, b.total_end, false)
    );
}

#[test]
fn the_demand_is_the_first_of_the_largest_complete_records_and_merged_ones_do_not_compete() {
    let mut ch = Channel::new("UTC", &["15min"], daily("15min"));
    ch.read(at("2026-12-04T23:40:00Z"), 0);
    ch.read(at("2026-12-05T00:00:01Z"), 1);
    ch.read(at("2026-12-05T00:15:01Z"), 40);
    ch.read(at("2026-12-05T00:30:01Z"), 90);
    ch.read(at("2026-12-05T00:45:01Z"), 90);
    // Away over 01:00: a merged record with more pulses than any, which must not count.
    ch.read(at("2026-12-05T01:15:01Z"), 500);
    ch.read(at("2026-12-06T00:00:02Z"), 3);
    // The first, partial day closed at the first boundary read, which closed no record: it
    // goes out with the next record.
    let first = &ch.records[0].1.booking.as_ref().unwrap().billing;
    assert_eq!(first.len(), 1);
    assert_eq!(first[0].status, PeriodStatus::Partial);
    assert_eq!(
        (first[0].delta, first[0].end_ms),
        (1, at("2026-12-05T00:00:00Z"))
    );
    let b = ch.account.kept.last().unwrap();
    assert_eq!(b.status, PeriodStatus::Complete);
    let peak = b.peak.unwrap();
    assert_eq!(
        (peak.delta, peak.start_ms),
        (90, at("2026-12-05T00:15:00Z"))
    );
    assert_eq!(peak.ms, 900_000);
    assert_eq!(b.delta, 40 + 90 + 90 + 500 + 3);
    assert_eq!(b.by_tariff.values().sum::<i64>(), b.delta);
}

#[test]
fn the_account_survives_a_save_and_a_restart_in_the_middle_of_a_period() {
    let mut ch = Channel::new("UTC", &["15min"], daily("15min"));
    ch.run(at("2026-12-04T10:00:05Z"), 60_000, 60, |_| 3);
    let saved = serde_json::to_string(&(&ch.account, &ch.states)).unwrap();
    let (account, states): (Account, Vec<IntervalState>) = serde_json::from_str(&saved).unwrap();
    ch.account = account;
    ch.states = states;
    ch.read(at("2026-12-04T23:30:01Z"), 7);
    ch.run(at("2026-12-04T23:45:01Z"), 60_000, 20, |_| 1);
    let b = ch.account.kept.last().unwrap();
    assert_eq!((b.start_ms, b.total_start), (at("2026-12-04T10:00:05Z"), 3));
    assert_eq!(b.delta, b.total_end - 3);
    assert_eq!(b.by_tariff.values().sum::<i64>(), b.delta);
}

/// Peak on Fridays in the last minute of the day (23:59-00:00), off-peak otherwise.
fn last_minute_peak() -> Calendar {
    Calendar::new(
        "offpeak",
        &[],
        &[RawRule {
            tariff: "peak".into(),
            days: vec!["fri".into()],
            from: "23:59".into(),
            to: "00:00".into(),
        }],
    )
    .unwrap()
}

/// The billing records the run closed, in order.
fn billing_records(ch: &Channel) -> Vec<&BillingRecord> {
    ch.records
        .iter()
        .flat_map(|(_, r)| &r.booking.as_ref().unwrap().billing)
        .collect()
}

#[test]
fn a_start_just_before_a_switch_books_the_boundary_reads_pulses_to_the_tariff_before_it() {
    // Friday 4 December 2026 (UTC): the gateway starts at 23:58:55.5, five seconds before
    // peak begins at a 10 s boundary, and reads every second, one pulse more each read. Its
    // read at 23:59:00.5 is the boundary read that opens the first record: its pulses, as
    // those of any record's end read, were counted before the boundary, in off-peak.
    let mut ch = Channel::new("UTC", &["10s"], daily("10s"));
    ch.calendar = last_minute_peak();
    let start = at("2026-12-04T23:58:55.500Z");
    ch.run(start, 1_000, 66, |t| (t - start) / 1_000);
    let billing = billing_records(&ch);
    assert_eq!(billing.len(), 1, "midnight closed the partial day");
    let b = billing[0];
    assert_eq!(b.status, PeriodStatus::Partial);
    assert_eq!(b.end_ms, at("2026-12-05T00:00:00Z"));
    let records: Vec<&Record> = ch
        .records
        .iter()
        .map(|(_, r)| r)
        .filter(|r| r.end_ms <= b.end_ms)
        .collect();
    assert_eq!(records[0].start_ms, at("2026-12-04T23:59:00Z"));
    // Every register is the running sum of its tariff's records.
    assert_eq!(ch.tariff_sums("10s"), ch.account.registers);
    // The period's peak is exactly its peak records; off-peak is the pulses no record holds,
    // those read before the first record's start boundary.
    let peak: i64 = records.iter().map(|r| r.delta).sum();
    assert_eq!(ch.account.registers["peak"], peak, "the minute is all peak");
    assert_eq!(b.by_tariff["peak"], peak, "{b:?}");
    assert_eq!(
        b.by_tariff["offpeak"],
        records[0].total_start - b.total_start
    );
    assert_eq!(b.by_tariff.values().sum::<i64>(), b.delta);
}

#[test]
fn a_partial_period_closed_by_the_first_boundary_read_is_booked_to_the_tariff_before_it() {
    // Started at 23:59:55.5 on a Friday, inside peak; the first boundary read is Saturday's
    // midnight, off-peak when it was read. It closes the partial day, which is all peak.
    let mut ch = Channel::new("UTC", &["10s"], daily("10s"));
    ch.calendar = last_minute_peak();
    ch.run(at("2026-12-04T23:59:55.500Z"), 1_000, 6, |_| 7);
    let pending = &ch.account.pending;
    assert_eq!(pending.len(), 1, "closed with no record: it waits for one");
    assert_eq!(pending[0].end_ms, at("2026-12-05T00:00:00Z"));
    assert_eq!(pending[0].delta, 5 * 7);
    assert_eq!(pending[0].by_tariff, BTreeMap::from([("peak".into(), 35)]));
}

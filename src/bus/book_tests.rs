//! The bus core's counting, pure: a driver's declarations and samples in, readings out, with no
//! driver, runtime or clock. Meter registers (the M-Bus shape) roll over at their own value and
//! a replaced meter is a `reset`, never a negative delta.

use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;
use std::time::{Duration, SystemTime};

use crate::bus::device::{DeviceRt, ProtocolError};
use crate::bus::driver::{DeviceState, Executed, Written, Wrote};
use crate::command::CommandError;
use crate::counter::{CounterState, Stamp};
use crate::event::Event;
use crate::profile::ChannelKind;
use crate::reading::Reading;
use crate::sample::{At, Channel, Counting, Direction, Sample, Wrap};

/// What the core told the driver's device state.
#[derive(Default)]
struct Told {
    resets: u32,
}

#[derive(Debug)]
struct Never;

impl std::fmt::Display for Never {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("never")
    }
}

impl ProtocolError for Never {
    fn device_answered(&self) -> bool {
        false
    }
}

impl DeviceState for Told {
    type Error = Never;

    fn reset_found(&mut self) {
        self.resets += 1;
    }
}

/// A device `m` (unit 1) with the counter states `saved`.
fn device(saved: &BTreeMap<String, CounterState>) -> DeviceRt<Told> {
    let dir = std::env::temp_dir().join("pulsegate-book-tests");
    let text = format!(
        "[gateway]\nid = \"t\"\nstate_dir = {dir:?}\n[buses.l]\nhost = \"127.0.0.1\"\nport = 1\n\
         [buses.l.devices.m]\nunit = 1\nmodel = \"yl67\"\n"
    );
    let config =
        crate::config::Config::from_toml(&text, &dir.join("t.toml"), Some(HashMap::new())).unwrap();
    let bus = &config.buses[0];
    DeviceRt::new(bus, &bus.devices[0], saved, Told::default())
}

fn at(ms: u64) -> At {
    At {
        wall: SystemTime::UNIX_EPOCH + Duration::from_millis(ms),
        stamp: Stamp::at(ms),
    }
}

const BCD_8: i64 = 100_000_000;
const U32: i64 = 1 << 32;

/// A device with one meter register `energy` rolling over at `rollover`, at most 100 steps a
/// second.
fn meter(rollover: i64) -> DeviceRt<Told> {
    let mut d = device(&BTreeMap::new());
    d.declare(vec![Channel {
        name: Arc::from("energy"),
        kind: ChannelKind::Counter,
        counting: Counting::Register {
            rollover,
            max_rate_hz: 100.0,
        },
        units: None,
    }]);
    d
}

/// Books register values read at (value, ms): the reading of each poll, if any.
fn read_register(
    d: &mut DeviceRt<Told>,
    rollover: i64,
    reads: &[(i64, u64)],
) -> Vec<Option<Reading>> {
    reads
        .iter()
        .map(|&(v, ms)| {
            let mut r = d.book_poll(vec![Sample::register(0, at(ms), v, rollover)]);
            assert!(r.len() <= 1);
            r.pop()
        })
        .collect()
}

#[test]
fn an_eight_digit_bcd_register_rolling_over_from_99_999_990_to_15_is_a_delta_of_25() {
    let mut d = meter(BCD_8);
    let r = read_register(&mut d, BCD_8, &[(99_999_990, 0), (15, 60_000)]);
    let first = r[0].as_ref().expect("the first read is a reading");
    assert_eq!((first.count, first.update.delta), (99_999_990, 0));
    let rolled = r[1].as_ref().expect("a roll-over is booked at once");
    assert_eq!(
        (rolled.count, rolled.update.delta, rolled.update.total),
        (15, 25, 25)
    );
    assert_eq!(rolled.update.event, Some(Event::Rollover));
    assert_eq!(d.proto.resets, 0, "a roll-over is no reset");
}

#[test]
fn a_register_that_drops_from_5_000_000_to_120_is_a_replaced_meter_a_reset_and_no_negative_delta() {
    let mut d = meter(BCD_8);
    let r = read_register(
        &mut d,
        BCD_8,
        &[
            (5_000_000, 0),
            (5_000_100, 60_000),
            // The old meter is gone; the new one stands at 120, then counts on.
            (120, 120_000),
            (150, 180_000),
            (170, 240_000),
        ],
    );
    assert_eq!(r[1].as_ref().unwrap().update.delta, 100);
    assert!(
        r[2].is_none(),
        "no roll-over explains the drop: held, not published"
    );
    let reset = r[3].as_ref().expect("the next read confirms a new meter");
    assert_eq!(reset.update.event, Some(Event::Reset));
    // Counted on from the new meter's first read: its 120 before that are no one's pulses.
    assert_eq!((reset.update.delta, reset.update.total), (30, 130));
    assert_eq!(r[4].as_ref().unwrap().update.delta, 20);
    let deltas: Vec<i64> = r.iter().flatten().map(|r| r.update.delta).collect();
    assert!(deltas.iter().all(|d| *d >= 0), "{deltas:?}");
    assert_eq!(d.proto.resets, 1, "the driver hears of the reset");
}

#[test]
fn a_32_bit_register_wraps_at_2_pow_32() {
    let mut d = meter(U32);
    let r = read_register(&mut d, U32, &[(4_294_967_290, 0), (10, 60_000)]);
    let wrapped = r[1].as_ref().expect("booked");
    assert_eq!(
        (wrapped.update.delta, wrapped.update.event),
        (16, Some(Event::Rollover))
    );
    // What an 8-digit register's roll-over is, a 32-bit one's is not: the read is held.
    let mut d = meter(U32);
    let r = read_register(&mut d, U32, &[(99_999_990, 0), (15, 60_000)]);
    assert!(r[1].is_none(), "{:?}", r[1]);
}

/// A device with one 32-bit pulse input `di1` counting up at up to 1 kHz.
fn input() -> DeviceRt<Told> {
    let mut d = device(&BTreeMap::new());
    d.declare(vec![Channel {
        name: Arc::from("di1"),
        kind: ChannelKind::Counter,
        counting: Counting::Count {
            wrap: UP_32,
            max_rate_hz: 1000.0,
        },
        units: None,
    }]);
    d
}

const UP_32: Wrap = Wrap {
    bits: 32,
    direction: Direction::Up,
};

#[test]
fn a_counter_the_driver_started_starts_over_with_a_reset_and_no_delta() {
    let mut d = input();
    d.book_poll(vec![Sample::count(0, at(0), 5000, UP_32)]);
    let started = Sample::count(0, at(1000), 3, UP_32)
        .with_rates(Some(2.0), Some(0.5))
        .starting_over();
    let r = d.book_poll(vec![started]);
    assert_eq!(
        (r[0].update.delta, r[0].update.total, r[0].update.event),
        (0, 0, Some(Event::Reset))
    );
    assert_eq!((r[0].freq_hz, r[0].rpm), (Some(2.0), Some(0.5)));
    assert_eq!(
        d.proto.resets, 0,
        "the driver started it: nothing to tell it"
    );
    let next = d.book_poll(vec![Sample::count(0, at(2000), 10, UP_32)]);
    assert_eq!(next[0].update.delta, 7);
}

#[test]
fn a_count_follows_the_direction_its_sample_wraps_in() {
    let mut d = input();
    d.book_poll(vec![Sample::count(0, at(0), 100, UP_32)]);
    let down = Wrap {
        bits: 32,
        direction: Direction::Down,
    };
    let r = d.book_poll(vec![Sample::count(0, at(500), 40, down)]);
    assert_eq!((r[0].update.delta, r[0].update.event), (-60, None));
}

#[test]
fn a_channel_resumes_its_saved_state_and_one_no_longer_declared_keeps_it() {
    let key = "1/yl67/di1".to_string();
    let state = CounterState {
        count: Some(1000),
        at_ms: 0,
        total: 77,
        seq: 9,
        ..Default::default()
    };
    let mut d = device(&BTreeMap::from([(key.clone(), state)]));
    let di1 = |counting| Channel {
        name: Arc::from("di1"),
        kind: ChannelKind::Counter,
        counting,
        units: None,
    };
    let count = Counting::Count {
        wrap: UP_32,
        max_rate_hz: 1000.0,
    };
    d.declare(vec![di1(count)]);
    let r = d.book_poll(vec![Sample::count(0, at(5000), 1500, UP_32)]);
    assert_eq!(
        (r[0].update.delta, r[0].update.total, r[0].update.seq),
        (500, 577, 10)
    );
    assert_eq!(r[0].update.event, Some(Event::Gap), "counted while away");
    // A work mode without it: its state is kept, and saved, for when it comes back.
    d.declare(Vec::new());
    assert_eq!(d.counter_states()[&key].total, 577);
    d.declare(vec![di1(count)]);
    let r = d.book_poll(vec![Sample::count(0, at(6000), 1600, UP_32)]);
    assert_eq!((r[0].update.delta, r[0].update.total), (100, 677));
}

#[test]
fn a_gauge_is_counted_by_no_one_and_published_as_its_value_in_its_unit() {
    use crate::config::units::ChannelUnits;
    use crate::decimal::Decimal;
    use crate::sample::Measure;
    let mut d = device(&BTreeMap::new());
    d.declare(vec![Channel {
        name: Arc::from("flow_temperature"),
        kind: ChannelKind::Counter,
        counting: Counting::Gauge,
        units: Some(ChannelUnits {
            unit: Some("°C".into()),
            ..ChannelUnits::default()
        }),
    }]);
    let value = Measure::Exact(Decimal::parse("61.5").unwrap());
    let r = d.book_poll(vec![Sample::gauge(0, at(0), value.clone())]);
    assert_eq!(r[0].measured, Some(value));
    assert!(r[0].is_gauge());
    assert!(d.counter_states().is_empty(), "nothing to save");
    let stray = Measure::Real(1.0);
    assert!(d.book_poll(vec![Sample::gauge(7, at(0), stray)]).is_empty());
}

#[test]
fn a_meter_registers_reading_starts_at_the_register_and_its_total_at_zero() {
    use crate::config::units::ChannelUnits;
    use crate::decimal::Decimal;
    let mut d = device(&BTreeMap::new());
    d.declare(vec![Channel {
        name: Arc::from("volume"),
        kind: ChannelKind::Counter,
        counting: Counting::Register {
            rollover: 100_000_000,
            max_rate_hz: 1000.0,
        },
        units: Some(ChannelUnits {
            scale: Some(Decimal::parse("0.001").unwrap()),
            unit: Some("m³".into()),
            ..ChannelUnits::default()
        }),
    }]);
    let r = d.book_poll(vec![Sample::register(0, at(0), 12_345, 100_000_000)]);
    assert_eq!((r[0].count, r[0].update.total), (12_345, 0));
    let meter = d.counter_states()["1/yl67/volume"].meter.clone().unwrap();
    assert_eq!(meter.offset, "12.345");
    // The reading moves with the total from there: 10 litres later it shows 12.355 m³.
    let r = d.book_poll(vec![Sample::register(0, at(1000), 12_355, 100_000_000)]);
    assert_eq!(r[0].update.total, 10);
    let again = d.counter_states()["1/yl67/volume"].meter.clone().unwrap();
    assert_eq!(again, meter, "set once, at the first read");
}

/// A clear of `di1` that read `before` ahead of the write and `back` after it.
fn cleared(before: i64, back: i64, elapsed_ms: u64) -> Executed {
    Executed {
        before: vec![Sample::count(0, at(1000), before, UP_32)],
        written: vec![Written {
            channel: 0,
            wrote: Wrote::Cleared,
            read_back: Some(Sample::count(0, at(1000 + elapsed_ms), back, UP_32)),
            elapsed_ms,
        }],
        failed: None,
    }
}

#[test]
fn a_clear_books_what_came_before_and_the_pulses_counted_while_writing() {
    let mut d = input();
    d.book_poll(vec![Sample::count(0, at(0), 500, UP_32)]);
    let (r, result) = d.book_command(cleared(700, 7, 10));
    assert_eq!(result, Ok(Some(7)), "the count read back");
    let got: Vec<_> = r
        .iter()
        .map(|r| (r.count, r.update.delta, r.update.total, r.update.event))
        .collect();
    assert_eq!(
        got,
        [(700, 200, 200, None), (7, 7, 207, Some(Event::Cleared))]
    );
}

#[test]
fn a_read_back_the_write_does_not_explain_is_an_error_and_counting_goes_on_from_it() {
    let mut d = input();
    d.book_poll(vec![Sample::count(0, at(0), 500, UP_32)]);
    let (r, result) = d.book_command(cleared(700, 90_000, 10));
    assert_eq!(
        result,
        Err(CommandError::ReadBack {
            expected: 0,
            got: 90_000
        })
    );
    assert_eq!(
        (r[1].update.delta, r[1].update.total),
        (0, 200),
        "nothing booked"
    );
    let next = d.book_poll(vec![Sample::count(0, at(2000), 90_100, UP_32)]);
    assert_eq!(next[0].update.delta, 100);
}

#[test]
fn a_command_that_failed_books_what_it_read_before() {
    let mut d = input();
    d.book_poll(vec![Sample::count(0, at(0), 500, UP_32)]);
    let mut failed = cleared(600, 0, 10);
    failed.written.clear();
    failed.failed = Some(CommandError::WriteFailed("no answer".into()));
    let (r, result) = d.book_command(failed);
    assert!(matches!(result, Err(CommandError::WriteFailed(_))));
    assert_eq!(r.len(), 1);
    assert_eq!(r[0].update.total, 100);
}

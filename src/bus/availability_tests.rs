//! Availability without a bus: events in, transitions out (and a 60 s outage in paused time).

use super::*;
use crate::bus::schedule::Slot;
use crate::log_budget::WINDOW as ERROR_LOG_EVERY;

const S: Duration = Duration::from_secs(1);

fn fresh() -> Availability {
    Availability::new(3, S, 8 * S)
}

fn timeout(a: &mut Availability) -> Verdict {
    a.failed("unit 1 did not answer within 100 ms".into(), false, false)
}

#[test]
fn the_first_good_answer_brings_a_device_online() {
    let mut a = fresh();
    assert_eq!(a.online(), None);
    assert_eq!(a.answered(), [Transition::Online { back: false }]);
    assert_eq!(a.online(), Some(true));
    assert_eq!(a.answered(), [], "nothing changes: nothing to say");
}

#[test]
fn a_device_goes_offline_at_the_third_consecutive_failure_and_not_before() {
    let mut a = fresh();
    a.answered();
    let first = timeout(&mut a);
    assert_eq!(
        first.transitions,
        [Transition::Error(
            "unit 1 did not answer within 100 ms".into()
        )]
    );
    assert_eq!(first.wait, None, "keeps its schedule");
    assert_eq!(
        timeout(&mut a).transitions,
        [],
        "the same error is said once"
    );
    let third = timeout(&mut a);
    assert_eq!(third.transitions, [Transition::Offline { failures: 3 }]);
    assert_eq!(third.wait, Some(S));
    assert_eq!(a.online(), Some(false));
}

#[test]
fn an_answer_between_failures_starts_the_count_again() {
    let mut a = fresh();
    a.answered();
    timeout(&mut a);
    timeout(&mut a);
    assert_eq!(a.answered(), [Transition::Recovered]);
    timeout(&mut a);
    timeout(&mut a);
    assert_eq!(a.online(), Some(true), "two failures since the answer");
}

#[test]
fn noise_is_asked_again_of_a_device_that_answers_and_silence_not_of_one_only_ever_silent() {
    let mut a = fresh();
    assert!(a.worth_retrying(true), "not yet seen but answering garbled");
    assert!(
        !a.worth_retrying(false),
        "not yet seen and silent: may be dead or late"
    );
    a.failed(
        "garbled answer (12 bytes, no valid frame)".into(),
        true,
        false,
    );
    assert!(
        a.worth_retrying(false),
        "it answered before: a lost request this time"
    );
    a.answered();
    assert!(a.worth_retrying(false), "online: a lost request or answer");
    for _ in 0..3 {
        timeout(&mut a);
    }
    assert_eq!(a.online(), Some(false));
    assert!(
        !a.worth_retrying(false),
        "offline and silent since: one try per probe"
    );
    assert!(
        a.worth_retrying(true),
        "offline but answering garbled: it is there"
    );
    a.failed(
        "garbled answer (3 bytes, no valid frame)".into(),
        true,
        false,
    );
    assert_eq!(a.online(), Some(false), "a garbled answer is no poll");
    assert!(a.worth_retrying(false), "heard again");
}

#[test]
fn an_exception_answer_is_no_step_towards_offline() {
    let mut a = fresh();
    a.answered();
    for _ in 0..10 {
        let v = a.failed("exception 02".into(), true, false);
        assert_eq!(v.wait, None);
    }
    assert_eq!(a.online(), Some(true));
    assert_eq!(a.last_error(), Some("exception 02"));
}

#[test]
fn offline_probes_back_off_doubling_up_to_the_maximum() {
    let mut a = fresh();
    let waits: Vec<_> = (0..8).filter_map(|_| timeout(&mut a).wait).collect();
    assert_eq!(waits, [S, 2 * S, 4 * S, 8 * S, 8 * S, 8 * S]);
}

#[test]
fn while_the_line_is_down_offline_devices_are_probed_at_the_minimum() {
    let mut a = fresh();
    for _ in 0..6 {
        a.failed("port gone".into(), false, true);
    }
    assert_eq!(a.failed("port gone".into(), false, true).wait, Some(S));
    assert!(a.line_back(), "offline: probe at once");
    assert_eq!(timeout(&mut a).wait, Some(S), "backoff starts again");
}

#[test]
fn an_offline_device_that_answers_is_back_online_with_a_fresh_backoff() {
    let mut a = fresh();
    for _ in 0..5 {
        timeout(&mut a);
    }
    assert_eq!(a.answered(), [Transition::Online { back: true }]);
    let v: Vec<_> = (0..3).map(|_| timeout(&mut a).wait).collect();
    assert_eq!(v, [None, None, Some(S)]);
}

#[test]
fn a_device_out_of_service_is_neither_online_nor_offline() {
    let mut a = fresh();
    a.answered();
    timeout(&mut a);
    a.out_of_service();
    assert_eq!(a.online(), None);
    assert_eq!(a.answered(), [Transition::Online { back: false }]);
}

/// The bus core's policy for a device polled every second that stops answering for 60 s:
/// the schedule and availability of the bus task, driven by tokio's paused clock (a minute in
/// a millisecond). Offline after 3 polls, probed at 1, 2, 4, 8, 8… s, back at the first probe
/// after the outage: it costs few transactions and the device is back within the backoff.
#[tokio::test(start_paused = true)]
async fn a_sixty_second_outage_costs_few_probes_and_ends_within_the_longest_backoff() {
    let start = tokio::time::Instant::now();
    let outage = start + Duration::from_secs(5)..start + Duration::from_secs(65);
    let mut a = fresh();
    let mut slot = Slot::new(start, S);
    let (mut asked_during, mut back_at, mut offline_at) = (0, None, None);
    while back_at.is_none() {
        tokio::time::sleep_until(slot.due).await;
        let now = tokio::time::Instant::now();
        if outage.contains(&now) {
            asked_during += 1;
            let v = timeout(&mut a);
            if v.transitions.contains(&Transition::Offline { failures: 3 }) {
                offline_at = Some(now);
            }
            match v.wait {
                Some(wait) => slot.defer_to(now + wait),
                None => slot.advance(now),
            }
        } else {
            if a.answered().contains(&Transition::Online { back: true }) {
                back_at = Some(now);
            }
            slot.advance(now);
        }
    }
    let offline_at = offline_at.expect("went offline");
    assert_eq!(offline_at - outage.start, 2 * S, "third poll of the outage");
    assert!(
        asked_during <= 3 + 10,
        "{asked_during} transactions in 60 s"
    );
    let back_after = back_at.unwrap() - outage.end;
    assert!(back_after <= 8 * S, "back {back_after:?} after the outage");
    assert!(
        start.elapsed() >= Duration::from_secs(65),
        "a minute went by on the clock"
    );
}

#[test]
fn a_noisy_device_writes_one_error_line_a_minute_and_counts_the_rest() {
    let mut a = fresh();
    let t0 = Instant::now();
    assert_eq!(a.may_log_error(t0), Some(0), "the first error is logged");
    for i in 1..=5 {
        assert_eq!(
            a.may_log_error(t0 + S * i),
            None,
            "error {i} within the minute"
        );
    }
    assert_eq!(
        a.may_log_error(t0 + ERROR_LOG_EVERY),
        Some(5),
        "the next line says how many were not logged"
    );
    assert_eq!(a.may_log_error(t0 + ERROR_LOG_EVERY + S), None);
}

#[test]
fn a_recovery_is_worth_a_line_only_after_a_logged_error() {
    let mut a = fresh();
    let t0 = Instant::now();
    assert!(!a.may_log_recovery(), "no error, no recovery to tell");
    a.may_log_error(t0);
    assert!(
        a.may_log_recovery(),
        "the error was logged: so is its recovery"
    );
    assert!(!a.may_log_recovery(), "once");
    a.may_log_error(t0 + S);
    assert!(
        !a.may_log_recovery(),
        "an error within the minute was not logged: neither is its recovery"
    );
}

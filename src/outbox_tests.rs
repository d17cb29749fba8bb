//! The outbox without a broker, in the manner of rumqttc's `state.rs` tests: events in, steps out.

use super::*;

fn t0() -> Instant {
    Instant::now()
}

fn msg(n: u64) -> Message {
    Message::new(format!("pg/t/d/c{n}"), format!("{{\"n\":{n}}}"), 1, false)
}

/// An outbox over a memory store of `max_bytes`, connected, with a window of `window`.
fn outbox(max_bytes: u64, window: usize) -> Outbox<MemoryStore> {
    let mut o = Outbox::new(MemoryStore::new(max_bytes), window, t0());
    o.connected(None, t0());
    o
}

/// Hands out everything the outbox offers; returns the sequence numbers sent.
fn pump(o: &mut Outbox<MemoryStore>) -> Vec<u64> {
    let mut sent = Vec::new();
    while let Some(step) = o.next(t0()) {
        if let Step::Send { entry: e, .. } = step {
            sent.push(e.seq);
        }
    }
    sent
}

fn enqueue(o: &mut Outbox<MemoryStore>, n: u64) {
    for i in 0..n {
        o.enqueue(msg(i)).unwrap();
    }
}

#[test]
fn enqueued_messages_are_handed_out_up_to_the_window_in_order() {
    let mut o = outbox(1 << 20, 3);
    enqueue(&mut o, 5);
    assert_eq!(pump(&mut o), [1, 2, 3]);
    assert_eq!(o.in_flight(), 3);
    assert_eq!(o.next(t0()), None, "the window is full");
}

#[test]
fn nothing_is_handed_out_while_the_broker_is_away() {
    let mut o = Outbox::new(MemoryStore::new(1 << 20), 3, t0());
    enqueue(&mut o, 2);
    assert_eq!(pump(&mut o), Vec::<u64>::new());
    assert_eq!(o.store().len(), 2, "stored meanwhile");
}

#[test]
fn an_acknowledgement_releases_its_message_and_opens_the_window() {
    let mut o = outbox(1 << 20, 2);
    enqueue(&mut o, 3);
    assert_eq!(pump(&mut o), [1, 2]);
    o.sent(11);
    o.sent(12);
    o.acked(11, t0());
    assert_eq!(pump(&mut o), [3]);
    assert_eq!(o.store().seqs(), [2, 3]);
}

#[test]
fn an_acknowledgement_that_overtakes_an_older_one_waits_for_it() {
    let mut o = outbox(1 << 20, 3);
    enqueue(&mut o, 3);
    pump(&mut o);
    for pkid in [1, 2, 3] {
        o.sent(pkid);
    }
    o.acked(2, t0());
    o.next(t0());
    assert_eq!(o.store().seqs(), [1, 2, 3], "1 is not acknowledged yet");
    o.acked(1, t0());
    o.next(t0());
    assert_eq!(o.store().seqs(), [3]);
}

#[test]
fn qos_0_messages_leave_when_sent() {
    let mut o = outbox(1 << 20, 2);
    o.enqueue(Message::new("pg/t/bus/l/stats".into(), "{}", 0, false))
        .unwrap();
    pump(&mut o);
    o.sent(0);
    o.next(t0());
    assert!(o.store().is_empty());
}

#[test]
fn a_full_spool_never_drops_what_is_in_flight() {
    // Room for about 4 messages; 3 in flight.
    let size = Entry::of(0, msg(0)).size();
    let mut o = outbox(4 * size, 3);
    enqueue(&mut o, 3);
    assert_eq!(pump(&mut o), [1, 2, 3]);
    enqueue(&mut o, 10); // seq 4..=13
    let seqs = o.store().seqs();
    assert_eq!(
        &seqs[..3],
        [1, 2, 3],
        "the client's messages are still stored"
    );
    assert_eq!(
        &seqs[3..],
        [13],
        "the oldest of the rest went, the newest stayed"
    );
    assert_eq!(o.evicted, 9);
}

#[test]
fn acknowledgements_after_an_eviction_release_the_right_messages() {
    let size = Entry::of(0, msg(0)).size();
    let mut o = outbox(5 * size, 3);
    enqueue(&mut o, 3);
    pump(&mut o);
    for pkid in [7, 8, 9] {
        o.sent(pkid);
    }
    enqueue(&mut o, 6); // 4..=9: 4..=7 are evicted
    assert_eq!(o.store().seqs(), [1, 2, 3, 8, 9]);
    o.acked(7, t0());
    o.acked(8, t0());
    assert_eq!(pump(&mut o), [8, 9], "the window opens by two");
    assert_eq!(o.store().seqs(), [3, 8, 9], "1 and 2 released, not 8 and 9");
    o.acked(9, t0());
    for pkid in [10, 11] {
        o.sent(pkid);
    }
    o.acked(10, t0());
    o.next(t0());
    assert_eq!(o.store().seqs(), [9], "3 and 8 released, 9 still in flight");
}

#[test]
fn a_reconnect_resends_in_order_what_was_not_acknowledged() {
    let mut o = outbox(1 << 20, 3);
    enqueue(&mut o, 5);
    assert_eq!(pump(&mut o), [1, 2, 3]);
    o.sent(1);
    o.sent(2);
    o.acked(1, t0());
    o.next(t0());
    o.lost();
    assert_eq!(o.in_flight(), 0, "the client's messages are gone with it");
    assert_eq!(pump(&mut o), Vec::<u64>::new());
    enqueue(&mut o, 1); // 6, while away
    o.connected(None, t0());
    assert_eq!(
        pump(&mut o),
        [2, 3, 4],
        "from the oldest unacknowledged, in order"
    );
    for pkid in [1, 2, 3] {
        o.sent(pkid);
        o.acked(pkid, t0());
    }
    assert_eq!(pump(&mut o), [5, 6]);
}

#[test]
fn a_packet_id_reused_after_a_reconnect_releases_the_new_message_only() {
    let mut o = outbox(1 << 20, 2);
    enqueue(&mut o, 3);
    pump(&mut o);
    o.sent(1);
    o.lost();
    o.acked(1, t0()); // a late acknowledgement of the old connection: nothing held
    o.connected(None, t0());
    assert_eq!(pump(&mut o), [1, 2]);
    o.sent(1);
    o.acked(1, t0());
    assert_eq!(pump(&mut o), [3]);
    assert_eq!(o.store().seqs(), [2, 3]);
}

#[test]
fn a_refused_hand_over_is_offered_again() {
    let mut o = outbox(1 << 20, 3);
    enqueue(&mut o, 2);
    assert!(matches!(o.next(t0()), Some(Step::Send { entry: e, .. }) if e.seq == 1));
    o.refused();
    assert_eq!(pump(&mut o), [1, 2]);
}

#[test]
fn an_unsendable_message_is_dropped_and_the_next_one_sent() {
    let mut o = outbox(1 << 20, 3);
    o.enqueue(Message::new("evil/#".into(), "{}", 1, false))
        .unwrap();
    o.enqueue(msg(1)).unwrap();
    assert!(matches!(o.next(t0()), Some(Step::Dropped { topic, .. }) if topic == "evil/#"));
    assert!(matches!(o.next(t0()), Some(Step::Send { entry: e, .. }) if e.topic == "pg/t/d/c1"));
    assert_eq!(o.store().seqs(), [2], "the wildcard one is gone");
}

#[test]
fn a_message_larger_than_the_broker_announced_is_dropped() {
    let mut o = outbox(1 << 20, 3);
    o.connected(Some(1024), t0());
    o.enqueue(Message::new("pg/t/big".into(), vec![b'x'; 2000], 1, false))
        .unwrap();
    assert!(matches!(o.next(t0()), Some(Step::Dropped { .. })));
}

#[test]
fn transient_messages_are_not_stored_while_the_broker_is_away() {
    let mut o = Outbox::new(MemoryStore::new(1 << 20), 3, t0());
    let mut stats = Message::new("pg/t/bus/l/stats".into(), "{}", 0, false);
    stats.transient = true;
    assert_eq!(o.enqueue(stats.clone()).unwrap(), Enqueued::Skipped);
    o.connected(None, t0());
    assert!(matches!(
        o.enqueue(stats).unwrap(),
        Enqueued::Stored { seq: 1, .. }
    ));
}

#[test]
fn messages_in_flight_without_an_acknowledgement_for_too_long_are_a_stalled_connection() {
    let start = t0();
    let mut o = outbox(1 << 20, 3);
    o.connected(None, start);
    enqueue(&mut o, 1);
    o.next(start);
    let limit = Duration::from_secs(10);
    assert!(!o.stalled(start + Duration::from_secs(9), limit));
    assert!(o.stalled(start + Duration::from_secs(11), limit));
    o.sent(1);
    o.acked(1, start + Duration::from_secs(11));
    o.next(start + Duration::from_secs(11));
    assert!(
        !o.stalled(start + Duration::from_secs(30), limit),
        "idle is not stalled"
    );
}

#[test]
fn direct_publishes_do_not_take_a_packet_id_of_the_window() {
    let mut o = outbox(1 << 20, 3);
    o.direct();
    enqueue(&mut o, 1);
    pump(&mut o);
    o.sent(5); // the status
    o.sent(6);
    o.acked(6, t0());
    o.next(t0());
    assert!(o.store().is_empty());
}

#[test]
fn binary_payloads_survive_the_stored_form() {
    let e = Entry::of(
        1,
        Message::new("t".into(), vec![0u8, 0xff, 0xfe, b'{'], 1, false),
    );
    let text = serde_json::to_string(&e).unwrap();
    assert_eq!(serde_json::from_str::<Entry>(&text).unwrap(), e);
    let json = Entry::of(2, Message::new("t".into(), "{\"a\":1}", 1, false));
    let text = serde_json::to_string(&json).unwrap();
    assert!(
        text.contains(r#""payload":"{\"a\":1}""#),
        "text stays text: {text}"
    );
    assert_eq!(serde_json::from_str::<Entry>(&text).unwrap(), json);
}

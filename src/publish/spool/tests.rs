use std::path::{Path, PathBuf};
use std::time::Duration;

use super::*;

fn dir(name: &str) -> PathBuf {
    let d = std::env::temp_dir().join(format!("pulsegate-spool-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&d);
    let _ = std::fs::remove_file(&d);
    d
}

fn push(s: &mut Spool, n: u64) {
    for i in 0..n {
        s.push(format!("t/{i}"), format!("{{\"n\":{i}}}"), 1, false, None);
    }
}

fn drain(s: &mut Spool) -> Vec<u64> {
    let mut out = Vec::new();
    while let Some(e) = s.get(0) {
        out.push(e.seq);
        s.ack_front(1);
    }
    out
}

fn names(d: &Path) -> Vec<String> {
    let mut names: Vec<String> = std::fs::read_dir(d)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .collect();
    names.sort();
    names
}

fn durable(s: &mut Spool) -> bool {
    s.durable().wait(Duration::from_secs(5))
}

/// The spool's directory becomes a file: every create in it fails (as on a full or broken
/// disk) until [`mend`] puts the directory back.
fn break_dir(d: &Path) {
    let _ = std::fs::remove_dir_all(d);
    std::fs::write(d, "not a directory").unwrap();
}

fn mend(d: &Path) {
    std::fs::remove_file(d).unwrap();
    std::fs::create_dir_all(d).unwrap();
}

#[test]
fn messages_come_out_in_order_and_leave_when_acknowledged() {
    let d = dir("order");
    let mut s = Spool::open(&d, 1 << 20).unwrap();
    push(&mut s, 5);
    assert_eq!(s.get(2).unwrap().seq, 3);
    s.ack_front(2);
    assert_eq!(s.len(), 3);
    assert_eq!(drain(&mut s), [3, 4, 5]);
    assert!(s.is_empty());
}

#[test]
fn while_the_broker_is_away_messages_go_to_disk_and_keep_their_order() {
    let d = dir("spill");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    push(&mut s, 3);
    s.set_spilling(true);
    push(&mut s, 4);
    s.spill();
    assert_eq!((s.on_disk(), s.in_memory_only()), (7, 0));
    s.set_spilling(false);
    push(&mut s, 2);
    assert_eq!(drain(&mut s), (1..=9).collect::<Vec<_>>());
    s.barrier().recv().unwrap();
    assert!(names(&d).is_empty(), "acknowledged files are deleted");
}

#[test]
fn the_spool_survives_a_restart() {
    let d = dir("restart");
    {
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        push(&mut s, 3);
        s.ack_front(1);
        s.set_spilling(true);
        push(&mut s, 2);
        s.spill();
    }
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    assert_eq!(s.len(), 4);
    assert_eq!(drain(&mut s), [2, 3, 4, 5]);
    let seq = s.push("t".into(), "x".into(), 1, false, None);
    assert_eq!(seq, 6, "sequence numbers go on after a restart");
}

#[test]
fn a_full_spool_drops_the_oldest_and_counts_them() {
    let d = dir("full");
    let mut s = Spool::open(&d, 100_000).unwrap();
    s.set_spilling(true);
    push(&mut s, 5000);
    assert!(s.dropped > 0);
    assert!(s.total_bytes() <= 100_000 + SEGMENT_BYTES);
    let left = drain(&mut s);
    assert_eq!(left.len() as u64 + s.dropped, 5000);
    assert!(left.windows(2).all(|w| w[0] < w[1]), "still in order");
    assert_eq!(*left.last().unwrap(), 5000, "the newest are kept");
}

#[test]
fn a_full_spool_on_disk_never_drops_what_the_outbox_has_in_flight() {
    use crate::outbox::{Message, Outbox, Step};
    let now = tokio::time::Instant::now();
    let d = dir("inflight");
    let mut spool = Spool::open(&d, 100_000).unwrap();
    spool.mem_limit = 1000;
    let mut o = Outbox::new(spool, 3, now);
    o.connected(None, now);
    let m = |i: u64| Message::new(format!("t/{i}"), format!("{{\"n\":{i}}}"), 1, false);
    for i in 0..3 {
        let _ = o.enqueue(m(i));
    }
    for pkid in 1..=3 {
        assert!(
            matches!(o.next(now), Some(Step::Send { entry: e, .. }) if e.seq == u64::from(pkid))
        );
        o.sent(pkid);
    }
    for i in 3..5000 {
        let _ = o.enqueue(m(i));
    }
    assert!(o.evicted > 0);
    let held: Vec<u64> = (0..3).map(|i| o.store_mut().get(i).unwrap().seq).collect();
    assert_eq!(held, [1, 2, 3], "the messages in flight are still stored");
    let oldest_left = o.store_mut().get(3).unwrap().seq;
    for pkid in 1..=3 {
        o.acked(pkid, now);
    }
    assert!(matches!(o.next(now), Some(Step::Send { entry: e, .. }) if e.seq == oldest_left));
    assert_eq!(
        o.store_mut().get(0).unwrap().seq,
        oldest_left,
        "1..=3 released"
    );
}

#[test]
fn a_binary_payload_comes_back_unchanged_after_a_restart() {
    let d = dir("binary");
    let payload = vec![0u8, 0xff, 0x80, b'\n', b'"'];
    {
        let mut s = Spool::open(&d, 64 << 20).unwrap();
        s.set_spilling(true);
        let m = crate::outbox::Message::new("t".into(), payload.clone(), 1, false);
        let _ = crate::outbox::Store::push(&mut s, m);
        s.spill();
    }
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    assert_eq!(&s.get(0).unwrap().payload[..], &payload[..]);
}

#[test]
fn memory_overflow_goes_to_disk_without_reordering() {
    let d = dir("overflow");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    s.mem_limit = 1000;
    push(&mut s, 100);
    s.barrier().recv().unwrap();
    assert!(!names(&d).is_empty());
    assert_eq!(drain(&mut s), (1..=100).collect::<Vec<_>>());
}

#[test]
fn a_spill_that_cannot_be_written_keeps_its_messages_in_memory_and_claims_none_on_disk() {
    let d = dir("spill-fails");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    push(&mut s, 5);
    s.set_spilling(true);
    break_dir(&d);
    s.spill();
    assert!(s.write_failures() > 0);
    assert_eq!((s.on_disk(), s.in_memory_only(), s.len()), (0, 5, 5));
    assert!(!durable(&mut s), "a checkpoint over them is not durable");
    mend(&d);
    assert!(durable(&mut s), "written at the next try");
    assert_eq!((s.on_disk(), s.in_memory_only()), (5, 0));
    drop(s);
    assert_eq!(Spool::open(&d, 64 << 20).unwrap().len(), 5);
}

#[test]
fn messages_that_arrive_while_writes_fail_wait_in_memory_in_order_and_are_written_at_the_next_flush()
 {
    let d = dir("tail-fails");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    s.mem_limit = 2000;
    s.set_spilling(true);
    push(&mut s, 3);
    s.flush();
    assert_eq!(s.on_disk(), 3);
    break_dir(&d);
    s.segments.clear(); // the directory and its files are gone with it
    s.appender = None;
    push(&mut s, 10);
    let failures = s.write_failures();
    assert!(failures > 0);
    push(&mut s, 2);
    assert_eq!(
        s.write_failures(),
        failures,
        "no new try before the next flush"
    );
    s.flush();
    assert!(s.write_failures() > failures, "tried again at the flush");
    assert_eq!(s.in_memory_only(), 12);
    mend(&d);
    s.flush();
    assert_eq!((s.on_disk(), s.in_memory_only()), (12, 0));
    assert_eq!(drain(&mut s), (4..=15).collect::<Vec<_>>());
}

#[test]
fn memory_for_messages_that_cannot_be_written_is_bounded_and_the_oldest_beyond_it_are_dropped() {
    let d = dir("tail-bound");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    s.mem_limit = 1000;
    s.set_spilling(true);
    break_dir(&d);
    push(&mut s, 100);
    assert!(s.tail_bytes <= 1000);
    assert!(s.dropped > 0);
    assert_eq!(s.len() + s.dropped, 100);
    mend(&d);
    let left = drain(&mut s);
    assert_eq!(*left.last().unwrap(), 100, "the newest are kept");
    assert!(left.windows(2).all(|w| w[0] < w[1]));
}

#[test]
fn a_spill_the_sync_thread_cannot_publish_is_taken_back_and_leaves_no_temp_file() {
    let d = dir("publish-fails");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    push(&mut s, 3);
    // Something in the way of the rename: a directory under the segment's name.
    let in_the_way = segment::path_of(&d, 1);
    std::fs::create_dir_all(in_the_way.join("x")).unwrap();
    assert!(!durable(&mut s));
    s.settle();
    assert_eq!((s.on_disk(), s.in_memory_only()), (0, 3));
    assert!(s.write_failures() > 0);
    assert!(
        !names(&d).iter().any(|n| n.ends_with(".tmp")),
        "{:?}",
        names(&d)
    );
    std::fs::remove_dir_all(&in_the_way).unwrap();
    assert!(durable(&mut s), "written again at the next try");
    assert_eq!(s.on_disk(), 3);
    assert!(in_the_way.is_file());
}

#[test]
fn a_bad_line_costs_only_that_line_and_its_file_is_set_aside_not_removed() {
    let d = dir("bad-line");
    std::fs::create_dir_all(&d).unwrap();
    let e = |seq| Entry {
        seq,
        topic: format!("t/{seq}"),
        payload: bytes::Bytes::from_static(b"x"),
        qos: 1,
        retain: false,
        correlation: None,
    };
    let mut bytes = segment::line(&e(1));
    bytes.extend_from_slice(b"\xff\xfe not utf-8\n");
    bytes.extend_from_slice(&segment::line(&e(3)));
    let path = segment::path_of(&d, 1);
    std::fs::write(&path, &bytes).unwrap();
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    assert_eq!(s.unreadable_lines(), 1);
    assert_eq!(drain(&mut s), [1, 3]);
    s.barrier().recv().unwrap();
    assert_eq!(names(&d), ["00000000000000000001.jsonl.unreadable"]);
    drop(s);
    assert!(
        Spool::open(&d, 64 << 20).unwrap().is_empty(),
        "never sent twice"
    );
}

#[test]
fn files_that_are_not_segments_are_never_touched_and_an_empty_segment_may_go() {
    let real = dir("foreign-target");
    std::fs::create_dir_all(&real).unwrap();
    let linked = dir("foreign-link");
    std::os::unix::fs::symlink(&real, &linked).unwrap();
    for (name, text) in [
        ("notes.jsonl", ""),
        ("readme.txt", "keep me"),
        ("1.jsonl", "{}\n"),
        ("00000000000000000009.jsonl.bak", ""),
    ] {
        std::fs::write(real.join(name), text).unwrap();
    }
    std::os::unix::fs::symlink(
        real.join("readme.txt"),
        real.join("00000000000000000005.jsonl"),
    )
    .unwrap();
    std::fs::write(real.join("00000000000000000007.jsonl"), "").unwrap();
    std::fs::write(real.join("00000000000000000008.tmp"), "half").unwrap();
    let mut s = Spool::open(&linked, 64 << 20).unwrap();
    assert!(s.is_empty());
    s.set_spilling(true);
    push(&mut s, 3);
    s.spill();
    assert_eq!(drain(&mut s), [1, 2, 3]);
    s.barrier().recv().unwrap();
    assert_eq!(
        names(&real),
        [
            "00000000000000000005.jsonl",
            "00000000000000000009.jsonl.bak",
            "1.jsonl",
            "notes.jsonl",
            "readme.txt"
        ],
        "the empty segment and the temp file a crash left are gone, nothing else"
    );
    assert_eq!(
        std::fs::read_to_string(real.join("readme.txt")).unwrap(),
        "keep me"
    );
}

#[test]
fn a_checkpoint_over_messages_on_a_healthy_disk_is_durable() {
    let d = dir("durable");
    let mut s = Spool::open(&d, 64 << 20).unwrap();
    push(&mut s, 3);
    s.set_spilling(true);
    push(&mut s, 3);
    assert!(durable(&mut s));
    assert_eq!(s.on_disk(), 6);
}

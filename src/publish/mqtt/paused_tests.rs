//! The output side on tokio's paused time: outages, stalls, floods, batches and Home Assistant's
//! re-announcements take milliseconds, with the real outbox, spool, stage and publisher (the
//! connection scripted, as in the other tests of the task).

use std::time::Duration;

use tokio::time::{Instant, advance};

use super::*;
use crate::command::CommandError;
use crate::outcome::{CommandOutcome, Outcome};
use crate::publish::lifecycle::Stage;

fn refused(n: usize) -> Output {
    Output::CommandResult {
        reply: crate::command::Reply {
            topics: vec!["pg/t/nosuch/cmd/result".into()],
            ..Default::default()
        },
        outcome: Outcome::Command(CommandOutcome {
            id: Some(format!("flood-{n}")),
            op: Some("clear_all".into()),
            result: Err(CommandError::UnknownDevice("nosuch".into())),
        }),
    }
}

/// Acknowledges everything the client holds, as a broker would; returns how many.
fn acknowledge_all(p: &mut Publisher<'_>, next_pkid: &mut u16) -> usize {
    let mut n = 0;
    while p.shell.outbox.in_flight() > 0 {
        for _ in 0..p.shell.outbox.in_flight() {
            *next_pkid = next_pkid.wrapping_add(1).max(1);
            p.polled(Ok(Event::Sent(*next_pkid)));
            p.polled(Ok(Event::Acked(*next_pkid)));
            n += 1;
        }
    }
    n
}

/// A minute without a broker: every reading is kept, in order, for the next connection, while
/// the command results of the minute neither enter the spool nor push a reading out of it.
#[tokio::test(start_paused = true)]
async fn a_minute_long_outage_keeps_every_reading_and_no_result_in_the_spool() {
    let task = task("paused-outage");
    let (mut p, _reports, _requests) = publisher(&task, "paused-outage");
    p.batch = Batch::new(Duration::ZERO);
    p.polled(Err(Failure::Other("connection refused".into())));
    let mut seq = 0;
    for second in 0..60 {
        for _ in 0..5 {
            seq += 1;
            p.handle(reading(seq));
            for n in 0..100 {
                p.handle(refused(second * 1000 + n));
            }
        }
        advance(Duration::from_secs(1)).await;
        p.beat(Instant::now());
    }
    assert_eq!(
        p.shell.outbox.store().len(),
        300,
        "every reading, nothing else"
    );
    assert_eq!(p.shell.outbox.store().dropped, 0);
    assert!(p.shell.outbox.chatter().len() <= crate::outbox::CHATTER_MESSAGES);
    p.polled(Ok(Event::ConnAck { max_packet: None }));
    let first = p.shell.outbox.store_mut().get(0).unwrap().clone();
    assert_eq!(
        &first.payload[..],
        payload_of(1),
        "the oldest reading first"
    );
}

fn payload_of(seq: u64) -> &'static [u8] {
    let Output::DeviceReadings { readings, .. } = reading(seq) else {
        unreachable!()
    };
    let r = &readings[0];
    Box::leak(
        crate::publish::payload::reading(r)
            .into_bytes()
            .into_boxed_slice(),
    )
}

/// A broker that takes messages but acknowledges none (SIGSTOP): a state save's checkpoint is
/// not answered while the readings before it exist in memory only; after its wait they are
/// synced in the spool, and only then is the save told to go on.
#[tokio::test(start_paused = true)]
async fn a_checkpoint_in_a_stall_is_answered_once_its_readings_are_on_disk() {
    let task = task("paused-stall");
    let (mut p, _reports, _requests) = publisher(&task, "paused-stall");
    for seq in 1..=20 {
        p.handle(reading(seq));
    }
    let (checkpoint, mut answer) = crate::reading::Checkpoint::new();
    p.handle(Output::Checkpoint(checkpoint));
    assert_eq!(
        p.shell.outbox.in_flight(),
        20,
        "handed over, not acknowledged"
    );
    assert!(answer.try_recv().is_err(), "not durable yet");
    assert_eq!(p.shell.outbox.store().written, 0, "nothing on disk yet");
    advance(Duration::from_millis(600)).await;
    p.beat(Instant::now());
    assert!(p.shell.outbox.store().written > 0, "spilled at the beat");
    assert_eq!(answer.await, Ok(true), "durable once synced");
    let reopened = crate::publish::spool::Spool::open(p.shell.outbox.store().dir(), 1 << 20);
    assert_eq!(
        reopened.unwrap().len(),
        20,
        "a crash now finds every reading"
    );
}

/// A healthy broker settles a checkpoint by acknowledging: no byte goes to disk for it.
#[tokio::test(start_paused = true)]
async fn a_checkpoint_the_broker_acknowledges_writes_nothing_to_disk() {
    let task = task("paused-acked");
    let (mut p, _reports, _requests) = publisher(&task, "paused-acked");
    for seq in 1..=20 {
        p.handle(reading(seq));
    }
    let (checkpoint, mut answer) = crate::reading::Checkpoint::new();
    p.handle(Output::Checkpoint(checkpoint));
    assert!(answer.try_recv().is_err());
    acknowledge_all(&mut p, &mut 0);
    assert_eq!(answer.try_recv(), Ok(true));
    advance(Duration::from_secs(2)).await;
    p.beat(Instant::now());
    assert_eq!(p.shell.outbox.store().written, 0);
}

/// Thirty thousand refused commands between the readings of a connected gateway whose broker
/// is slower than the flood: the results wait in their own bounded queue (the oldest dropped
/// and counted), every reading stays owed and none is evicted, however small the spool.
#[tokio::test(start_paused = true)]
async fn a_flood_of_refused_commands_never_pushes_out_a_reading() {
    let task = task("paused-flood");
    let (mut p, _reports, _requests) = publisher(&task, "paused-flood");
    let mut seq = 0;
    for n in 0..30_000 {
        p.handle(refused(n));
        if n % 100 == 0 {
            seq += 1;
            p.handle(reading(seq));
        }
    }
    let outbox = &p.shell.outbox;
    assert_eq!(outbox.store().len(), seq, "every reading owed");
    assert_eq!(outbox.store().dropped + outbox.evicted, 0);
    assert!(outbox.chatter().dropped > 0, "results dropped first");
    assert!(outbox.chatter().len() <= crate::outbox::CHATTER_MESSAGES);
    let mut pkid = 0;
    acknowledge_all(&mut p, &mut pkid);
    assert!(p.shell.outbox.store().is_empty(), "all readings delivered");
}

/// A batch ends on tokio's clock: held readings wait for their window, then go together.
#[tokio::test(start_paused = true)]
async fn held_readings_leave_when_the_batch_window_ends() {
    let task = task("paused-batch");
    let (mut p, _reports, _requests) = publisher(&task, "paused-batch");
    p.handle(reading(1));
    advance(Duration::from_millis(100)).await;
    p.handle(reading(2));
    assert_eq!(p.shell.outbox.in_flight(), 0, "held");
    let started = Instant::now();
    due(&mut p.batch_due).await;
    assert_eq!(
        Instant::now() - started,
        Duration::from_millis(150),
        "250 ms after the first"
    );
    p.pump();
    assert_eq!(p.shell.outbox.in_flight(), 2, "together");
}

/// Home Assistant's `online` 600 times at 40 a second (a flapping Home Assistant): every config
/// is announced at the first, then at most once per gap while they keep coming, and the
/// configs are chatter (never owed, never on disk).
#[tokio::test(start_paused = true)]
async fn a_flood_of_home_assistant_online_costs_one_announcement_per_gap() {
    let config = config("[homeassistant]\ndiscovery = true\n");
    let mut stage = Stage::new(super::formats_of(&config));
    let configs = stage.start().len();
    assert!(configs > 0);
    let mut sent = Vec::new();
    let mut next_tick = Instant::now() + Duration::from_secs(1);
    for _ in 0..600 {
        sent.extend(stage.received("homeassistant/status", b"online").messages);
        advance(Duration::from_millis(25)).await;
        if Instant::now() >= next_tick {
            sent.extend(stage.tick(Instant::now()));
            next_tick += Duration::from_secs(1);
        }
    }
    for _ in 0..6 {
        advance(Duration::from_secs(1)).await;
        sent.extend(stage.tick(Instant::now()));
    }
    let announcements = sent.len() / configs;
    assert_eq!(sent.len() % configs, 0, "whole announcements");
    assert!(
        (3..=4).contains(&announcements),
        "15 s of online: at 0, 5, 10 and (pending) 15 s, not 600 times: {announcements}"
    );
    assert!(
        sent.iter()
            .all(|m| m.class == crate::outbox::Class::Chatter)
    );
}

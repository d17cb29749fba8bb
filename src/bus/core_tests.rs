//! The protocol-neutral bus core in process, over a scripted driver and tokio's paused clock:
//! a minute of outage or a command's priority in milliseconds, no port and no simulator. The
//! real-time tests against the simulator (tests/integration) prove the Modbus driver.

use std::collections::HashMap;
use std::ops::Range;
use std::sync::{Arc, Mutex};

use tokio::sync::mpsc::unbounded_channel;

use super::device::ProtocolError;
use super::driver::{DeviceState, Driver, Executed, Preempt, Written, Wrote};
use super::*;
use crate::profile::ChannelKind;
use crate::reading::Reading;
use crate::sample::{At, Channel, Counting, Direction, Sample, Wrap};

/// A driver whose device answers except during `outage` (time since the start); it logs what
/// the bus asked of it, and each transaction takes 50 ms. Its device has one encoder channel,
/// `enc0`, declared at the first answer; each poll reads it `pulses` further on (`None`: the
/// poll reads nothing), and a clear reads back 0.
struct Scripted {
    start: Instant,
    outage: Range<Duration>,
    log: Arc<Mutex<Vec<(Duration, &'static str)>>>,
    pulses: Option<i64>,
}

const ENCODER: Wrap = Wrap {
    bits: 32,
    direction: Direction::Both,
};

impl Scripted {
    fn note(&self, what: &'static str) -> Duration {
        let at = self.start.elapsed();
        self.log.lock().unwrap().push((at, what));
        at
    }

    /// Now on the paused clock, as the counter sees it.
    fn at(&self) -> At {
        let ms = self.start.elapsed().as_millis() as u64;
        At {
            wall: std::time::SystemTime::UNIX_EPOCH + Duration::from_millis(ms),
            stamp: crate::counter::Stamp::at(ms),
        }
    }
}

/// The scripted protocol's per-device state: what the core told it, saved with the bus's state
/// (under the key `scripted`, as the Modbus driver saves its holes under the device's key).
#[derive(Default)]
struct Heard {
    failed: u16,
    offline: u16,
    declared: bool,
    count: i64,
}

/// The scripted protocol's one failure.
#[derive(Debug)]
struct NoAnswer;

impl std::fmt::Display for NoAnswer {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.write_str("no answer")
    }
}

impl ProtocolError for NoAnswer {
    fn device_answered(&self) -> bool {
        false
    }
}

impl DeviceState for Heard {
    type Error = NoAnswer;

    fn poll_failed(&mut self, _: &PollError<NoAnswer>) {
        self.failed += 1;
    }

    fn went_offline(&mut self) {
        self.offline += 1;
    }

    fn save(&self, state: &mut BusState) {
        let heard = vec![(self.failed, self.offline)];
        state.holes.insert("scripted".into(), heard);
    }

    fn saved_key(&self) -> Option<String> {
        Some("scripted".into())
    }
}

impl Driver for Scripted {
    type Device = Heard;

    fn device(&self, _: &Bus, _: &crate::config::Device, _: &BusState) -> Heard {
        Heard::default()
    }

    async fn poll(
        &mut self,
        d: &mut DeviceRt<Heard>,
        _: Preempt<'_>,
    ) -> Result<Vec<Sample>, PollError<NoAnswer>> {
        tokio::time::sleep(Duration::from_millis(50)).await;
        if self.outage.contains(&self.note("poll")) {
            return Err(PollError::Protocol(NoAnswer));
        }
        if !std::mem::replace(&mut d.proto.declared, true) {
            d.declare(vec![Channel {
                name: "enc0".into(),
                kind: ChannelKind::Encoder,
                counting: Counting::Count {
                    wrap: ENCODER,
                    max_rate_hz: 1000.0,
                },
                units: None,
            }]);
        }
        let Some(pulses) = self.pulses else {
            return Ok(Vec::new());
        };
        d.proto.count += pulses;
        Ok(vec![Sample::count(0, self.at(), d.proto.count, ENCODER)])
    }

    async fn execute(&mut self, d: &mut DeviceRt<Heard>, _: &Request) -> Executed {
        tokio::time::sleep(Duration::from_millis(50)).await;
        self.note("execute");
        d.proto.count = 0;
        Executed {
            written: vec![Written {
                channel: 0,
                wrote: Wrote::Cleared,
                read_back: Some(Sample::count(0, self.at(), 0, ENCODER)),
                elapsed_ms: 0,
            }],
            ..Executed::default()
        }
    }

    fn wire(&self) -> (WireCounters, Duration) {
        (WireCounters::default(), Duration::ZERO)
    }

    fn is_line_fault(&self, _: &PollError<NoAnswer>) -> bool {
        false
    }

    fn ready_for_commands(&self, _: &DeviceRt<Heard>) -> bool {
        true
    }

    fn close(&mut self) {}
}

/// A bus of one device polled every second, offline after 3 failures, probed 1 s → 8 s.
fn config(name: &str) -> crate::config::Config {
    let dir = std::env::temp_dir().join(format!("pulsegate-core-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let text = format!(
        "[gateway]\nid = \"t\"\nstate_dir = {dir:?}\nstats_interval = \"1h\"\n\
         [buses.l]\nhost = \"127.0.0.1\"\nport = 1\noffline_after = 3\nbackoff_min = \"1s\"\n\
         backoff_max = \"8s\"\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\npoll = \"1s\"\n"
    );
    crate::config::Config::from_toml(&text, &dir.join("t.toml"), Some(HashMap::new())).unwrap()
}

struct Running {
    log: Arc<Mutex<Vec<(Duration, &'static str)>>>,
    out: tokio::sync::mpsc::UnboundedReceiver<Output>,
    commands: UnboundedSender<BusCommand>,
    stop: CancellationToken,
    task: tokio::task::JoinHandle<()>,
}

/// A bus of `n` devices polled every millisecond: saturated, every device always overdue.
fn saturated(name: &str, n: u8) -> crate::config::Config {
    let dir = std::env::temp_dir().join(format!("pulsegate-core-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let mut text = format!(
        "[gateway]\nid = \"t\"\nstate_dir = {dir:?}\nstats_interval = \"1h\"\n\
         [buses.l]\nhost = \"127.0.0.1\"\nport = 1\n"
    );
    for unit in 1..=n {
        text += &format!(
            "[buses.l.devices.d{unit}]\nunit = {unit}\nmodel = \"yl67\"\npoll = \"1ms\"\n"
        );
    }
    crate::config::Config::from_toml(&text, &dir.join("t.toml"), Some(HashMap::new())).unwrap()
}

fn start(name: &str, outage: Range<Duration>) -> Running {
    start_with(config(name), outage)
}

/// What the MQTT task does for a bus: answers its state saves' checkpoints (everything is
/// durable at once here, or, `answer` false, never: a broker that never acknowledges and a
/// disk that never syncs) and passes the rest on.
fn answering_checkpoints(
    mut out: tokio::sync::mpsc::UnboundedReceiver<Output>,
    answer: bool,
) -> tokio::sync::mpsc::UnboundedReceiver<Output> {
    let (tx, rx) = unbounded_channel();
    tokio::spawn(async move {
        let mut unanswered = Vec::new();
        while let Some(o) = out.recv().await {
            match o {
                Output::Checkpoint(c) if answer => c.answer(true),
                Output::Checkpoint(c) => unanswered.push(c),
                o => {
                    let _ = tx.send(o);
                }
            }
        }
    });
    rx
}

fn start_with(config: crate::config::Config, outage: Range<Duration>) -> Running {
    start_answering(config, outage, true)
}

fn start_answering(
    config: crate::config::Config,
    outage: Range<Duration>,
    answer: bool,
) -> Running {
    start_counting(config, outage, answer, None)
}

fn start_counting(
    config: crate::config::Config,
    outage: Range<Duration>,
    answer: bool,
    pulses: Option<i64>,
) -> Running {
    let (out_tx, out) = unbounded_channel();
    let out = answering_checkpoints(out, answer);
    let (commands, rx) = unbounded_channel();
    let heart = crate::health::Health::default().heart(crate::health::Loop::Bus("l".into()));
    let task = BusTask::new(config.buses[0].clone(), &config.gateway, out_tx, rx, heart);
    let log = Arc::new(Mutex::new(Vec::new()));
    let driver = Scripted {
        start: Instant::now(),
        outage,
        log: log.clone(),
        pulses,
    };
    let stop = CancellationToken::new();
    let task = tokio::spawn(task.run(driver, stop.clone()));
    Running {
        log,
        out,
        commands,
        stop,
        task,
    }
}

fn statuses(out: &mut tokio::sync::mpsc::UnboundedReceiver<Output>) -> Vec<bool> {
    let mut seen = Vec::new();
    while let Ok(o) = out.try_recv() {
        if let Output::DeviceStatus { online, .. } = o {
            seen.push(online);
        }
    }
    seen
}

#[tokio::test(start_paused = true)]
async fn a_sixty_second_outage_takes_the_device_offline_and_back_with_few_probes() {
    let secs = Duration::from_secs;
    let mut bus = start("outage", secs(5)..secs(65));
    tokio::time::sleep(secs(80)).await;
    bus.stop.cancel();
    bus.task.await.unwrap();
    assert_eq!(
        statuses(&mut bus.out),
        [true, false, true, false],
        "online, offline in the outage, online after it, offline at shutdown"
    );
    let log = bus.log.lock().unwrap();
    let during = log
        .iter()
        .filter(|(at, _)| (secs(5)..secs(65)).contains(at));
    let probes = during.count();
    assert!(probes <= 13, "{probes} transactions in the 60 s outage");
    let back = log.iter().find(|(at, _)| *at >= secs(65)).unwrap().0;
    assert!(back <= secs(65 + 8), "asked again {back:?} after the start");
}

/// The core counts for every driver: a scripted one's samples become readings (deltas, totals,
/// seq) booked by the bus core and saved with the bus's state; the driver never counts.
#[tokio::test(start_paused = true)]
async fn the_core_books_a_scripted_drivers_samples_into_readings_and_saves_the_total() {
    let config = config("counts");
    let path = crate::state::bus_path(&config.gateway.state_dir, "l");
    let mut bus = start_counting(config, Duration::ZERO..Duration::ZERO, true, Some(5));
    tokio::time::sleep(Duration::from_millis(3500)).await;
    bus.stop.cancel();
    bus.task.await.unwrap();
    let mut readings = Vec::new();
    while let Ok(o) = bus.out.try_recv() {
        if let Output::DeviceReadings { readings: r, .. } = o {
            readings.extend(r);
        }
    }
    let got: Vec<(i64, i64, i64, u64)> = readings
        .iter()
        .map(|r| (r.count, r.update.delta, r.update.total, r.update.seq))
        .collect();
    assert_eq!(
        got,
        [(5, 0, 0, 1), (10, 5, 5, 2), (15, 5, 10, 3), (20, 5, 15, 4)]
    );
    let saved = BusState::load(&path).unwrap();
    assert_eq!(saved.channels["1/yl67/enc0"].total, 15);
}

#[tokio::test(start_paused = true)]
async fn the_protocols_own_device_state_hears_the_outage_and_is_saved_with_the_bus() {
    let secs = Duration::from_secs;
    let config = config("heard");
    let path = crate::state::bus_path(&config.gateway.state_dir, "l");
    let mut bus = start_with(config, secs(5)..secs(65));
    tokio::time::sleep(secs(80)).await;
    bus.stop.cancel();
    bus.task.await.unwrap();
    assert_eq!(statuses(&mut bus.out), [true, false, true, false]);
    let saved = BusState::load(&path).unwrap();
    // One new error (the same one repeats through the outage), one offline; no Modbus type.
    assert_eq!(saved.holes.get("scripted"), Some(&vec![(1, 1)]));
}

#[tokio::test(start_paused = true)]
async fn a_command_goes_on_the_line_before_the_next_poll() {
    let mut bus = start("command", Duration::ZERO..Duration::ZERO);
    tokio::time::sleep(Duration::from_millis(2300)).await;
    let (done, result) = oneshot::channel();
    let now = Instant::now();
    let request = Request {
        device: "d".into(),
        channel: None,
        op: crate::command::Op::ClearAll,
        id: None,
        reply: Default::default(),
        received: now,
        expires: now + Duration::from_secs(5),
    };
    bus.commands.send(BusCommand { request, done }).unwrap();
    assert_eq!(result.await.unwrap(), Ok(Some(0)));
    let sent_at = Duration::from_millis(2300);
    let next = bus
        .log
        .lock()
        .unwrap()
        .iter()
        .find(|(at, _)| *at > sent_at)
        .copied();
    assert_eq!(next.map(|(_, what)| what), Some("execute"));
    assert!(
        next.unwrap().0 < sent_at + Duration::from_millis(100),
        "at once, not after a poll"
    );
    bus.stop.cancel();
    bus.task.await.unwrap();
    assert_eq!(statuses(&mut bus.out), [true, false]);
}

fn clear_all(
    device: &str,
) -> (
    BusCommand,
    oneshot::Receiver<Result<Option<i64>, CommandError>>,
) {
    let (done, result) = oneshot::channel();
    let now = Instant::now();
    let request = Request {
        device: device.into(),
        channel: None,
        op: crate::command::Op::ClearAll,
        id: None,
        reply: Default::default(),
        received: now,
        expires: now + Duration::from_secs(30),
    };
    (BusCommand { request, done }, result)
}

#[tokio::test(start_paused = true)]
async fn on_a_saturated_bus_commands_and_polls_take_turns() {
    // Eight devices always overdue, 50 ms a transaction: a whole round of polls is 400 ms.
    let bus = start_with(saturated("turns", 8), Duration::ZERO..Duration::ZERO);
    tokio::time::sleep(Duration::from_secs(2)).await;
    let mut waits = Vec::new();
    let burst_from = Instant::now();
    for _ in 0..10 {
        let (command, result) = clear_all("d1");
        let sent = Instant::now();
        bus.commands.send(command).unwrap();
        assert_eq!(result.await.unwrap(), Ok(Some(0)));
        waits.push(sent.elapsed());
        // The next command comes a little later, as an operator's or a script's would.
        tokio::time::sleep(Duration::from_millis(137)).await;
    }
    let burst = burst_from.elapsed();
    let log = bus.log.lock().unwrap().clone();
    bus.stop.cancel();
    let from = Duration::from_secs(2);
    let polls = log
        .iter()
        .filter(|(at, what)| *at >= from && *at <= from + burst && *what == "poll")
        .count();
    // A command waits for the poll in flight and the polls it owes for the last command's line
    // time: about two transactions, never a whole round of the overdue devices.
    let longest = waits.iter().max().unwrap();
    assert!(
        *longest <= Duration::from_millis(200),
        "a command waited {longest:?}: {waits:?}"
    );
    // And the commands never starve polling: the polls go on between them.
    assert!(polls >= 20, "{polls} polls during 10 commands in {burst:?}");
}

/// After a clean stop the state file is durable as it stands: the next run's first readings go
/// out at once, not when its first save is done (a crash right after that save would otherwise
/// take their deltas, the pulses of the whole stop, with it). After a crash they wait for the
/// save that makes the moved seqs durable.
#[tokio::test(start_paused = true)]
async fn after_a_clean_stop_the_first_readings_go_out_before_any_save() {
    let config = config("trust");
    let bus = &config.buses[0];
    let mut saved = BusState {
        clean: true,
        ..BusState::default()
    };
    let state = crate::counter::CounterState {
        seq: 40,
        ..Default::default()
    };
    saved.channels.insert("1/yl67/enc0".into(), state);
    let devices = one_device(bus, &saved.channels);
    let first_out = |trusted: bool| {
        let (out_tx, mut out) = unbounded_channel();
        let saver = saver::Saver::new(std::env::temp_dir().join("never-written"), "l".into());
        let mut durable = durable::Durable::new(saver, &Default::default(), Default::default());
        if trusted {
            durable.trust(&saved);
        }
        durable.publish(vec![reading_of(41)], 0, &devices, &out_tx);
        out.try_recv().unwrap()
    };
    assert!(
        matches!(first_out(true), Output::DeviceReadings { .. }),
        "sent at once"
    );
    assert!(
        matches!(first_out(false), Output::Checkpoint(_)),
        "not trusted: held for a save, whose checkpoint goes first"
    );
}

fn reading_of(seq: u64) -> Output {
    Output::single(Reading::sample("d", "enc0", seq))
}

/// A record saved as closed is in the state file as unsent until it has gone out: a crash
/// between that save and the hand-over no longer loses it (the next start takes it out of the
/// file and sends it again), and the save after the hand-over leaves it out (a later start
/// does not send it twice).
#[tokio::test]
async fn a_record_saved_closed_stays_in_the_file_as_unsent_until_it_went_out() {
    use crate::metering::Status;
    use crate::reading::IntervalRecord;
    let config = config("unsent");
    let bus = &config.buses[0];
    // The channel's state as the read that closed the record left it: record 1 of `10s`.
    let mut state = crate::counter::CounterState::default();
    state.intervals.entry("10s".into()).or_default().seq = 1;
    let mut saved = BusState::default();
    saved.channels.insert("1/yl67/enc0".into(), state);
    let devices = one_device(bus, &saved.channels);
    let (path, saver) = saver_in(&config);
    let mut durable = durable::Durable::new(saver, &Default::default(), Default::default());
    let (out_tx, mut out) = unbounded_channel();
    let record = closed_record(1, Status::Complete, crate::event::Event::Reset);
    let output = Output::Interval(Box::new(IntervalRecord {
        device: devices[0].name.clone(),
        channel: "enc0".into(),
        period: "10s".into(),
        record: record.clone(),
        units: None,
    }));
    durable.publish(vec![output], 0, &devices, &out_tx);
    let Ok(Output::Checkpoint(c)) = out.try_recv() else {
        panic!("held for a save: its checkpoint goes first")
    };
    c.answer(true);
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    let sent = loop {
        durable.collect(&devices, &out_tx).await;
        if let Ok(o) = out.try_recv() {
            break o;
        }
        assert!(std::time::Instant::now() < deadline, "never released");
        tokio::time::sleep(Duration::from_millis(2)).await;
    };
    assert!(matches!(sent, Output::Interval(_)), "{sent:?}");

    // A crash now: the file holds the record, and the next start takes it out to send again.
    let mut file = BusState::load(&path).unwrap();
    let unsent = durable::take_unsent(&mut file.channels);
    assert_eq!(unsent["1/yl67/enc0"], vec![("10s".to_string(), record)]);
    assert!(
        file.channels["1/yl67/enc0"].intervals["10s"]
            .unsent
            .is_empty()
    );

    // The next save, after the record went out, leaves it out.
    durable
        .saver
        .start(durable.snapshot(&devices, false), &out_tx);
    let Ok(Output::Checkpoint(c)) = out.try_recv() else {
        panic!("a checkpoint")
    };
    c.answer(true);
    loop {
        durable.collect(&devices, &out_tx).await;
        let file = BusState::load(&path).unwrap();
        if durable::take_unsent(&mut file.channels.clone()).is_empty() {
            break;
        }
        assert!(std::time::Instant::now() < deadline, "still unsent");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
}

/// The start after a crash sends the records its state file holds as unsent, with their seq
/// and content, before anything else of the device; the clean stop after leaves none.
#[tokio::test(start_paused = true)]
async fn the_start_after_a_crash_sends_the_unsent_records_of_the_file_first() {
    use crate::metering::Status;
    let config = config("resend");
    let record = closed_record(4, Status::Merged, crate::event::Event::Gap);
    let mut state = crate::counter::CounterState::default();
    let st = state.intervals.entry("10s".into()).or_default();
    st.seq = 4;
    st.unsent.push(record.clone());
    let mut file = BusState::default();
    file.channels.insert("1/yl67/enc0".into(), state);
    std::fs::create_dir_all(&config.gateway.state_dir).unwrap();
    let path = crate::state::bus_path(&config.gateway.state_dir, "l");
    file.save(&path).unwrap();

    let mut bus = start_with(config, Duration::ZERO..Duration::ZERO);
    tokio::time::sleep(Duration::from_secs(3)).await;
    bus.stop.cancel();
    bus.task.await.unwrap();
    let mut outs = Vec::new();
    while let Ok(o) = bus.out.try_recv() {
        outs.push(o);
    }
    let first = outs
        .iter()
        .position(|o| matches!(o, Output::Interval(_) | Output::DeviceReadings { .. }))
        .expect("something was sent");
    let Output::Interval(i) = &outs[first] else {
        panic!("the unsent record goes first: {:?}", outs[first])
    };
    assert_eq!(
        (&*i.device, &*i.channel, &*i.period, &i.record),
        ("d", "enc0", "10s", &record)
    );
    let again = outs
        .iter()
        .filter(|o| matches!(o, Output::Interval(_)))
        .count();
    assert_eq!(again, 1, "sent once");
    let mut after = BusState::load(&path).unwrap();
    assert!(
        durable::take_unsent(&mut after.channels).is_empty(),
        "none left after a clean stop"
    );
}

/// A record of `10s` closed with `event` in it.
fn closed_record(
    seq: u64,
    status: crate::metering::Status,
    event: crate::event::Event,
) -> crate::metering::Record {
    crate::metering::Record {
        start_ms: 100_000,
        end_ms: 110_000,
        delta: 5,
        total_start: 7,
        total_end: 12,
        lag_start_ms: 50,
        lag_end_ms: 40,
        status,
        seq,
        events: vec![event],
        booking: None,
    }
}

/// Readings held for a save and released after it: a crash between the save and their
/// hand-over is covered, since the file says which reading was handed over last, and the next
/// start counts from it and carries the rest.
#[tokio::test]
async fn a_save_with_readings_held_writes_the_last_reading_handed_over() {
    let config = config("handed");
    let bus = &config.buses[0];
    let key = "1/yl67/enc0".to_string();
    let file_state = crate::counter::CounterState {
        seq: 5,
        total: 100,
        ..Default::default()
    };
    let saved = std::collections::BTreeMap::from([(key.clone(), file_state)]);
    let mut devices = one_device(bus, &saved);
    let (path, saver) = saver_in(&config);
    // After a crash (no trust): the first readings wait for a save.
    let mut resumed = saved.clone();
    let resume = super::ledger::resume(&mut resumed, true);
    let mut durable = durable::Durable::new(saver, &resumed, resume);
    // Two readings of this run, seq 1006 and 1007, total 130: held, the counter moved on.
    let live = devices[0].saved.get_mut(&key).unwrap();
    (live.seq, live.total) = (1007, 130);
    let reading = |seq: u64, total: i64| {
        let mut r = Reading::sample("d", "enc0", seq);
        r.update.total = total;
        Output::single(r)
    };
    let held = vec![reading(1006, 120), reading(1007, 130)];
    let (out_tx, mut out) = unbounded_channel();
    durable.publish(held, 0, &devices, &out_tx);
    let Ok(Output::Checkpoint(c)) = out.try_recv() else {
        panic!("held for a save")
    };
    c.answer(true);
    let deadline = std::time::Instant::now() + Duration::from_secs(5);
    while out.is_empty() {
        durable.collect(&devices, &out_tx).await;
        assert!(std::time::Instant::now() < deadline, "never released");
        tokio::time::sleep(Duration::from_millis(2)).await;
    }
    let Ok(Output::DeviceReadings { mut readings, .. }) = out.try_recv() else {
        panic!("the first held reading")
    };
    let first = readings.remove(0);
    assert_eq!(
        first.after_seq,
        Some(5),
        "counts from the crashed run's save"
    );

    // A crash now: the file says the last reading handed over is the file's own (5, 100), so
    // the next start counts from seq 5 and carries the 30 pulses of the two readings.
    let mut file = BusState::load(&path).unwrap();
    assert_eq!(
        file.channels[&key].handed,
        Some(crate::counter::Handed { seq: 5, total: 100 })
    );
    let next = super::ledger::resume(&mut file.channels, true);
    assert_eq!((next[&key].after_seq, next[&key].carry), (Some(5), 30));
}

/// The first device of `bus` with the counter states `saved`.
fn one_device(
    bus: &crate::config::Bus,
    saved: &std::collections::BTreeMap<String, crate::counter::CounterState>,
) -> Vec<DeviceRt<Heard>> {
    vec![DeviceRt::new(bus, &bus.devices[0], saved, Heard::default())]
}

/// A saver writing the state file of bus `l` in the config's state directory.
fn saver_in(config: &crate::config::Config) -> (std::path::PathBuf, saver::Saver) {
    std::fs::create_dir_all(&config.gateway.state_dir).unwrap();
    let path = config.gateway.state_dir.join("l.json");
    (path.clone(), saver::Saver::new(path, "l".into()))
}

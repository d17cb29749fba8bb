//! The MQTT task without a broker: its shell, publisher and batch, their connection scripted.

use super::*;
use crate::outbox::Message;
use crate::publish::session::{EventLoop, Options, Settings};

#[test]
fn a_wildcard_topic_can_never_be_sent() {
    assert!(unsendable("evil/#", 10, 0, None).is_some());
    assert!(unsendable("a/+/b", 10, 0, None).is_some());
    assert!(unsendable("", 10, 0, None).is_some());
    assert!(unsendable("pulsegate/e1/press/enc0", 100, 0, None).is_none());
}

/// A connected shell with a client whose requests go nowhere (its event loop is returned to
/// keep the queue open, never polled).
fn shell(name: &str) -> (Shell, EventLoop) {
    let dir = std::env::temp_dir().join(format!("pulsegate-mqtt-{name}-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&dir);
    let (client, eventloop) = Options::new(Settings {
        protocol: crate::config::MqttProtocol::V5,
        client_id: "t",
        host: "127.0.0.1",
        port: 1,
        keep_alive: Duration::from_secs(30),
        max_incoming: MAX_PACKET,
        inflight: INFLIGHT,
        login: None,
        transport: None,
    })
    .connect(None, 1 << 20);
    let mut shell = Shell::new(
        Spool::open(&dir, 1 << 20).unwrap(),
        client,
        Topics::new("pg/t"),
    );
    shell.outbox.connected(None, Instant::now());
    (shell, eventloop)
}

fn message(topic: &str) -> Message {
    Message::new(topic.into(), "{}", 1, false)
}

/// What rumqttc does after a packet-id collision: the publish was taken but nothing is
/// acknowledged any more, while pings go on. The gateway counts that as not publishing.
#[test]
fn messages_in_flight_without_an_acknowledgement_for_too_long_are_a_stalled_connection() {
    let (mut s, _requests) = shell("stall");
    s.queue(message("pg/t/d/enc0"));
    s.pump(&mut Stage::new(Vec::new()));
    assert_eq!(s.outbox.in_flight(), 1);
    let limit = Duration::from_secs(10);
    let now = Instant::now();
    assert!(!s.outbox.stalled(now, limit));
    let later = now + Duration::from_secs(11);
    assert!(
        s.outbox.stalled(later, limit),
        "nothing acknowledged for 11 s"
    );
    s.outbox.sent(1);
    s.outbox.acked(1, later);
    s.pump(&mut Stage::new(Vec::new()));
    assert_eq!(s.outbox.in_flight(), 0);
    assert!(!s.outbox.stalled(later, limit), "acknowledged: publishing");
}

#[test]
fn an_unsendable_message_is_dropped_and_the_next_one_sent() {
    let (mut s, _requests) = shell("unsendable");
    s.queue(message("evil/#"));
    s.queue(message("pg/t/ok"));
    s.pump(&mut Stage::new(Vec::new()));
    assert_eq!(s.outbox.store().len(), 1, "the wildcard one is gone");
    assert_eq!(s.outbox.in_flight(), 1);
    assert_eq!(s.outbox.store_mut().get(0).unwrap().topic, "pg/t/ok");
}

#[test]
fn a_message_larger_than_the_broker_takes_can_never_be_sent() {
    assert!(unsendable("t", 2000, 0, Some(1024)).is_some());
    assert!(unsendable("t", 200, 900, Some(1024)).is_some());
    assert!(unsendable("t", 200, 0, Some(1024)).is_none());
}

/// The config of the task's tests: one device `d`, plus `extra` TOML.
fn config(extra: &str) -> Config {
    let text = format!(
        "[gateway]\nid = \"t\"\n[mqtt]\nhost = \"127.0.0.1\"\nport = 1\ntopic_root = \"pg/t\"\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n{extra}"
    );
    let env = Some(std::collections::HashMap::new());
    Config::from_toml(&text, std::path::Path::new("x.toml"), env).expect("config")
}

fn task(name: &str) -> Task {
    let config = config("");
    let health = std::sync::Arc::new(crate::health::Health::default());
    Task {
        name: "json".into(),
        spool_dir: std::env::temp_dir().join(format!("pulsegate-mqtt-{name}")),
        flush_every: Duration::from_secs(1),
        heart: health.heart(crate::health::Loop::Output("json".into())),
        boot: crate::boot::Boot::default(),
        metrics: crate::metrics::OutputMetrics::default(),
        formats: Vec::new(),
        config: config.mqtt,
        voice: true,
        answers: tokio::sync::mpsc::unbounded_channel().0,
        controls: tokio::sync::mpsc::unbounded_channel().0,
        config_hash: String::new(),
        remote_config: false,
    }
}

/// The formats of the config's first output.
pub(super) fn formats_of(config: &Config) -> Vec<Box<dyn crate::publish::lifecycle::MqttFormat>> {
    super::super::formats::build(config, &config.outputs.list[0])
}

/// The task's state over a connected shell, its connection scripted by the test.
fn publisher<'t>(task: &'t Task, name: &str) -> (Publisher<'t>, Sender<Polled>, EventLoop) {
    let (shell, eventloop) = shell(name);
    let (poller, reports) = Poller::scripted();
    let link = Connection {
        dialer: crate::publish::dialer::Dialer::new(&task.config).unwrap(),
        broker: "127.0.0.1:1".into(),
        client_id: "t".into(),
        commands: true,
        voice: true,
        remote: false,
        boot: task.boot.clone(),
        config_hash: String::new(),
    };
    let (router, _) = tokio::sync::mpsc::channel(1);
    let p = Publisher {
        task,
        stage: Stage::new(formats_of(&config(""))),
        reloads: tokio::sync::mpsc::unbounded_channel().1,
        shell,
        link,
        watch: Watch::new(),
        poller,
        routes: Routes {
            to_task: Vec::new(),
            router,
            via: crate::command::Via {
                output: "json".into(),
                wrote: None,
            },
        },
        stall_after: Duration::from_secs(10),
        batch: Batch::new(task.config.batch),
        batch_due: None,
        checkpoints: Vec::new(),
        held_since: None,
        certificates_at: tokio::time::Instant::now(),
    };
    (p, reports, eventloop)
}

/// With two tasks sharing the shell, an acknowledgement of the stalled connection could
/// still arrive after the outbox had given its messages up. Now the reports come on the
/// connection's own channel, which goes with it.
#[tokio::test]
async fn a_stalled_connection_is_rebuilt_and_its_late_acknowledgements_release_nothing() {
    let task = task("rebuild");
    let (mut p, old, _requests) = publisher(&task, "rebuild");
    let status = Output::DeviceStatus {
        device: "d".into(),
        online: true,
    };
    p.handle(status);
    p.polled(Ok(Event::Sent(1)));
    assert_eq!(p.shell.outbox.in_flight(), 1);
    p.beat(Instant::now() + Duration::from_secs(11));
    assert!(!p.shell.outbox.is_connected(), "stalled: counted as lost");
    assert_eq!(p.shell.outbox.store().len(), 1, "kept to be sent again");
    assert!(
        old.try_send(Ok(Event::Acked(1))).is_err(),
        "the old connection's reports go nowhere"
    );
    // The fresh connection: the boot marker and the online status (packet ids 1 and 2)
    // go first, then the message again; its acknowledgement releases it.
    p.polled(Ok(Event::ConnAck { max_packet: None }));
    assert_eq!(p.shell.outbox.in_flight(), 1);
    for pkid in 1..=3 {
        p.polled(Ok(Event::Sent(pkid)));
    }
    p.polled(Ok(Event::Acked(1)));
    assert_eq!(
        p.shell.outbox.store().len(),
        1,
        "packet 1 was the boot marker"
    );
    p.polled(Ok(Event::Acked(3)));
    assert!(p.shell.outbox.store().is_empty());
    assert_eq!(p.watch.up, Some(true));
}

#[tokio::test]
async fn a_failed_connection_is_replaced_after_its_back_off_and_a_takeover_backs_off_longer() {
    let task = task("failed");
    let (mut p, _old, _requests) = publisher(&task, "failed");
    p.polled(Err(Failure::Other("connection refused".into())));
    assert!(!p.shell.outbox.is_connected());
    assert_eq!(
        (p.watch.up, p.watch.pause),
        (Some(false), Duration::from_secs(1))
    );
    p.polled(Err(Failure::TakenOver));
    assert_eq!(p.watch.pause, Duration::from_secs(5));
    p.polled(Ok(Event::Acked(9)));
    assert_eq!(
        p.watch.pause,
        Duration::from_secs(1),
        "an acknowledgement resets it"
    );
    // The client dropped (the gateway stopping) is no failure: nothing is rebuilt.
    p.polled(Ok(Event::ConnAck { max_packet: None }));
    p.polled(Err(Failure::RequestsDone));
    assert!(p.shell.outbox.is_connected());
}

/// A message larger than the gateway takes, skipped by rumqttc: counted, and no reason to
/// give the connection up (before, it cost the connection at every reconnect).
#[tokio::test]
async fn a_message_too_large_to_take_is_counted_and_the_connection_kept() {
    let mut task = task("too-large");
    let metrics = crate::metrics::Metrics::new();
    task.metrics = metrics.output("json");
    let (mut p, _reports, _requests) = publisher(&task, "too-large");
    for _ in 0..3 {
        p.polled(Ok(Event::TooLarge {
            topic: "pg/t/d/enc0/cmd".into(),
            size: 300_000,
        }));
    }
    assert!(p.shell.outbox.is_connected(), "not counted as lost");
    let dropped = "pulsegate_mqtt_messages_dropped_total{output=\"json\",reason=\"too_large\"} 3";
    assert!(metrics.encode().contains(dropped), "{}", metrics.encode());
}

fn reading(seq: u64) -> Output {
    Output::single(crate::reading::Reading::sample("d", "enc0", seq))
}

/// Readings wait for their batch (an acknowledgement of something else does not send them);
/// a state save's checkpoint, or any other message, takes them along.
#[tokio::test]
async fn held_readings_go_with_a_checkpoint_and_not_with_an_acknowledgement() {
    let task = task("batch");
    assert_eq!(task.config.batch, Duration::from_millis(250), "the default");
    let (mut p, _reports, _requests) = publisher(&task, "batch");
    p.handle(reading(1));
    p.handle(reading(2));
    assert_eq!(p.shell.outbox.in_flight(), 0, "held");
    assert_eq!(p.shell.outbox.store().len(), 2, "but in the spool already");
    p.polled(Ok(Event::Acked(7)));
    assert_eq!(p.shell.outbox.in_flight(), 0, "still held");
    p.handle(Output::Checkpoint(crate::reading::Checkpoint::new().0));
    assert_eq!(
        p.shell.outbox.in_flight(),
        2,
        "sent before the save records them"
    );
    assert!(!p.batch.holding());
    p.handle(reading(3));
    assert_eq!(p.shell.outbox.in_flight(), 2);
    p.handle(Output::DeviceStatus {
        device: "d".into(),
        online: true,
    });
    assert_eq!(p.shell.outbox.in_flight(), 4, "in order, with the status");
}

/// A batch that goes with a later poll's reading takes its timer with it: a timer left
/// behind fired later and, finished, was ready at every turn of the task's loop (a busy
/// loop until the next reading: 5 ms of CPU per RTU transaction with per-device payloads).
#[tokio::test]
async fn a_batch_sent_with_a_reading_leaves_no_timer_behind() {
    let task = task("batch-timer");
    let (mut p, _reports, _requests) = publisher(&task, "batch-timer");
    p.batch = Batch::new(Duration::from_millis(4));
    p.handle(reading(1));
    assert!(p.batch_due.is_some(), "the window's end is timed");
    std::thread::sleep(Duration::from_millis(4));
    p.handle(reading(2));
    assert_eq!(
        p.shell.outbox.in_flight(),
        2,
        "sent with the second reading"
    );
    assert!(p.batch_due.is_none(), "and the timer with them");
}

#[path = "paused_tests.rs"]
mod paused;

/// rumqttc's queue refuses a publish outside the outbox (full): it is not counted as sent by
/// us, so the next send event still belongs to the stored message it is for.
#[test]
fn a_direct_publish_the_client_refuses_does_not_take_a_stored_messages_send_event() {
    let (mut s, _requests) = shell("direct-refused");
    let (client, _small) = client_options(&task("direct-refused").config)
        .unwrap()
        .connect(None, 1);
    s.client = client;
    for i in 0..3 {
        s.publish_direct(Message::new(format!("pg/t/direct/{i}"), "x", 1, false));
    }
    // One was taken (and will have its send event), two were refused.
    s.queue(message("pg/t/d/enc0"));
    let (roomy, _roomy_requests) = shell("direct-refused-2");
    s.client = roomy.client;
    s.pump(&mut Stage::new(Vec::new()));
    assert_eq!(s.outbox.in_flight(), 1);
    s.outbox.sent(1); // the direct one that was taken
    s.outbox.sent(2); // the stored message
    s.outbox.acked(2, Instant::now());
    s.pump(&mut Stage::new(Vec::new()));
    assert_eq!(s.outbox.in_flight(), 0, "its acknowledgement released it");
}

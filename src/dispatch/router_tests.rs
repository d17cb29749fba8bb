//! The router in sentences: events in, actions out, no broker, no bus, no runtime.

use std::collections::{BTreeSet, HashMap};
use std::path::Path;

use super::*;

const CONFIG: &str = r#"
[gateway]
id = "e1"
[mqtt]
topic_root = "pg/e1"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.locked]
unit = 1
model = "yl67"
commands = false
[buses.line1.devices.open]
unit = 2
model = "yl67"
"#;

fn config() -> Config {
    Config::from_toml(
        CONFIG,
        Path::new("/etc/pulsegate.toml"),
        Some(HashMap::new()),
    )
    .unwrap()
}

fn router() -> Router {
    Router::new(&config(), &BTreeSet::from(["line1".to_string()]))
}

fn message(topic: &str, payload: &str, response_topic: Option<&str>) -> Event {
    Event::Message(Incoming {
        topic: topic.into(),
        payload: Bytes::from(payload.to_string()),
        retain: false,
        response_topic: response_topic.map(Into::into),
        correlation: None,
        via: None,
    })
}

/// The one result an action publishes: its topics and outcome as JSON.
fn result(actions: &[Action]) -> (Vec<String>, serde_json::Value) {
    let [Action::Publish(Output::CommandResult { reply, outcome })] = actions else {
        panic!("one result: {actions:?}");
    };
    (reply.topics.clone(), outcome.to_json())
}

/// The one command an action forwards.
fn forwarded(mut actions: Vec<Action>) -> (String, Box<Request>, Pending) {
    assert_eq!(actions.len(), 1, "{actions:?}");
    let Some(Action::Forward(bus, request, pending)) = actions.pop() else {
        panic!("forwarded: {actions:?}");
    };
    (bus, request, pending)
}

#[test]
fn a_scan_leaves_out_the_units_of_devices_with_commands_false() {
    let mut r = router();
    let actions = r.handle(
        message("pg/e1/bus/line1/scan", r#"{"units":"1-3"}"#, None),
        Instant::now(),
    );
    let [Action::Scan(bus, request)] = &actions[..] else {
        panic!("the scan goes to its bus: {actions:?}");
    };
    assert_eq!(bus, "line1");
    assert_eq!(
        request.units,
        [2, 3],
        "unit 1 (commands = false) is neither asked nor listed; unit 2 is listed as configured"
    );
}

#[test]
fn a_response_topic_into_the_gateways_own_topics_is_answered_on_the_result_topic_only() {
    let mut r = router();
    for (topic, response) in [
        ("pg/e1/open/enc0/cmd", "pg/e1/status"),
        ("pg/e1/open/enc0/cmd", "pg/e1/open/status"),
        ("pg/e1/open/enc0/cmd", "pg/e1/open/enc1"),
        ("pg/e1/open/enc0/cmd", "homeassistant/status"),
        ("pg/e1/bus/line1/scan", "pg/e1/line1/status"),
    ] {
        let actions = r.handle(
            message(topic, r#"{"op":"clear"}"#, Some(response)),
            Instant::now(),
        );
        let (topics, _) = result(&actions);
        assert_eq!(topics, [format!("{topic}/result")], "{response}");
    }
}

#[test]
fn a_command_to_an_unknown_device_or_a_locked_one_is_refused_without_a_bus() {
    let mut r = router();
    let now = Instant::now();
    let (_, ghost) = result(&r.handle(
        message("pg/e1/ghost/enc0/cmd", r#"{"op":"clear"}"#, None),
        now,
    ));
    assert_eq!(ghost["error"], "unknown_device");
    let (_, locked) = result(&r.handle(
        message("pg/e1/locked/enc0/cmd", r#"{"op":"clear"}"#, None),
        now,
    ));
    assert_eq!(locked["error"], "disabled");
    let (_, channel) = result(&r.handle(
        message("pg/e1/open/nope/cmd", r#"{"op":"clear"}"#, None),
        now,
    ));
    assert_eq!(channel["error"], "unknown_channel");
}

#[test]
fn a_command_goes_to_its_bus_and_its_answer_is_published_and_remembered_for_a_repeat() {
    let mut r = router();
    let now = Instant::now();
    let clear = r#"{"op":"clear","id":"c1"}"#;
    let (bus, request, pending) =
        forwarded(r.handle(message("pg/e1/open/enc0/cmd", clear, None), now));
    assert_eq!((bus.as_str(), request.device.as_str()), ("line1", "open"));
    assert_eq!(request.expires, now + EXPIRY);
    assert!(
        r.handle(message("pg/e1/open/enc0/cmd", clear, None), now)
            .is_empty(),
        "a repeat while the first is in flight waits for its answer"
    );
    let (topics, answer) = result(&r.handle(Event::Answered(pending, Ok(Some(0))), now));
    assert_eq!(topics, ["pg/e1/open/enc0/cmd/result"]);
    assert_eq!(
        (answer["ok"].clone(), answer["id"].clone()),
        (true.into(), "c1".into())
    );
    let (_, again) = result(&r.handle(message("pg/e1/open/enc0/cmd", clear, None), now));
    assert_eq!(
        again, answer,
        "a repeat after the answer gets the same answer, no second clear"
    );
}

#[test]
fn a_device_busy_with_a_command_refuses_the_next_until_its_bus_answers() {
    let mut r = router();
    let now = Instant::now();
    let (_, _, first) = forwarded(r.handle(
        message("pg/e1/open/enc0/cmd", r#"{"op":"clear"}"#, None),
        now,
    ));
    let mut refused = 0;
    for _ in 0..50 {
        let actions = r.handle(
            message("pg/e1/open/enc0/cmd", r#"{"op":"clear"}"#, None),
            now,
        );
        if matches!(&actions[..], [Action::Publish(_)]) {
            refused += 1;
        }
    }
    assert!(
        refused > 0,
        "a flood to one device is refused (busy), not queued without bound"
    );
    r.handle(Event::Answered(first, Ok(None)), now);
    let later = now + Duration::from_secs(60);
    forwarded(r.handle(
        message("pg/e1/open/enc0/cmd", r#"{"op":"clear"}"#, None),
        later,
    ));
}

#[test]
fn a_scan_or_push_the_shell_could_not_hand_on_is_answered_busy() {
    let mut r = router().with_remote();
    let now = Instant::now();
    let reply = Reply {
        topics: vec!["pg/e1/bus/line1/scan/result".into()],
        ..Reply::default()
    };
    let refusal = ScanRefusal::Busy;
    let event = Event::ScanNotTaken {
        bus: "line1".into(),
        reply,
        refusal,
    };
    let (topics, busy) = result(&r.handle(event, now));
    assert_eq!(topics, ["pg/e1/bus/line1/scan/result"]);
    assert_eq!(busy["error"], "busy", "{busy}");
    let push = message("pg/e1/config/set", r#"{"id":"p1","toml":""}"#, None);
    let [Action::Push(msg)] = &r.handle(push, now)[..] else {
        panic!("a push goes to the remote task");
    };
    let event = Event::PushNotTaken {
        msg: msg.clone(),
        closed: true,
    };
    let (topics, answer) = result(&r.handle(event, now));
    assert_eq!(topics, ["pg/e1/config/result"]);
    assert_eq!(
        (answer["error"].clone(), answer["id"].clone()),
        ("busy".into(), "p1".into())
    );
}

#[test]
fn a_reload_that_stops_a_bus_leaves_its_devices_unknown() {
    let mut r = router();
    let now = Instant::now();
    r.handle(
        Event::Reconfigured(targets_of(&config(), &BTreeSet::new())),
        now,
    );
    let (_, answer) = result(&r.handle(
        message("pg/e1/open/enc0/cmd", r#"{"op":"clear"}"#, None),
        now,
    ));
    assert_eq!(answer["error"], "unknown_device");
}

#[test]
fn a_retained_command_or_a_push_without_remote_does_nothing() {
    let mut r = router();
    let Event::Message(mut m) = message("pg/e1/open/enc0/cmd", r#"{"op":"clear"}"#, None) else {
        unreachable!()
    };
    m.retain = true;
    assert!(r.handle(Event::Message(m), Instant::now()).is_empty());
    let push = message("pg/e1/config/set", r#"{"id":"p1","toml":""}"#, None);
    assert!(r.handle(push, Instant::now()).is_empty());
}

#[test]
fn a_cleared_retained_push_is_no_push_and_a_busy_answer_keeps_a_large_pushs_id() {
    let mut r = router().with_remote();
    let now = Instant::now();
    assert!(
        r.handle(message("pg/e1/config/set", "", None), now)
            .is_empty(),
        "an empty message clears a retained push: it takes no place from the next"
    );
    let big = format!(r#"{{"id":"big","toml":"{}"}}"#, "x".repeat(300 * 1024));
    let [Action::Push(msg)] = &r.handle(message("pg/e1/config/set", &big, None), now)[..] else {
        panic!("a push goes to the remote task, which judges it");
    };
    let event = Event::PushNotTaken {
        msg: msg.clone(),
        closed: false,
    };
    let (_, answer) = result(&r.handle(event, now));
    assert_eq!(answer["id"], "big", "{answer}");
}

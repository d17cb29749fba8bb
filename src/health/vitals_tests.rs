//! The vitals in sentences: each test tells events at made-up instants and asks at others.

use super::*;

fn bus(n: &str) -> Loop {
    Loop::Bus(n.into())
}

fn output(n: &str) -> Loop {
    Loop::Output(n.into())
}

/// A gateway started at `t0` with these loops registered then.
fn gateway(t0: Instant, loops: &[Loop]) -> Vitals {
    let mut v = Vitals::new(t0);
    for l in loops {
        v.handle(Event::Registered(l.clone()), t0);
    }
    v
}

fn secs(n: u64) -> Duration {
    Duration::from_secs(n)
}

#[test]
fn a_loop_that_stops_beating_is_stale_and_one_that_beats_is_not() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[bus("a"), bus("b")]);
    v.handle(Event::Beat(bus("a")), t0 + secs(9));
    assert!(v.stale(t0 + secs(10), secs(3)) == ["bus/b"]);
    assert!(
        v.stale(t0 + secs(2), secs(3)).is_empty(),
        "both fresh at first"
    );
    let why = v.verdict(t0 + secs(10), secs(3)).unwrap_err();
    assert_eq!(why, "not making progress: bus/b");
}

#[test]
fn the_status_line_counts_buses_devices_and_mqtt() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[bus("a"), bus("b"), output("json")]);
    v.handle(Event::Up(bus("a"), true), t0);
    v.handle(Event::Up(output("json"), true), t0);
    v.handle(Event::Device("press".into(), true), t0);
    v.handle(Event::Device("doors".into(), false), t0);
    assert_eq!(
        v.status_line(),
        "1/2 buses up, 1/2 devices online, MQTT connected"
    );
    assert_eq!(v.online_devices(), ["press"]);
    v.handle(Event::DevicesKept(vec!["doors".into()]), t0);
    assert_eq!(
        v.status_line(),
        "1/2 buses up, 0/1 devices online, MQTT connected",
        "a reload forgets the press"
    );
}

#[test]
fn ready_waits_for_every_loop_to_start() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[bus("a")]);
    v.handle(Event::Beat(bus("a")), t0);
    assert!(!v.all_started(), "running is not yet having tried the line");
    v.handle(Event::Up(bus("a"), false), t0);
    assert!(v.all_started());
}

#[test]
fn a_bus_that_is_not_polling_is_not_well() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[output("json"), bus("a")]);
    v.handle(Event::Up(output("json"), true), t0);
    v.handle(Event::Up(bus("a"), true), t0);
    assert!(v.verdict(t0, secs(60)).is_ok());
    let refused = Some("state file refused, not polling".to_string());
    v.handle(Event::Problem(bus("a"), refused), t0);
    let why = v.verdict(t0, secs(60)).unwrap_err();
    assert!(why.contains("bus/a not polling"), "{why}");
    assert!(why.contains("state file refused"), "{why}");
    v.handle(Event::Problem(bus("a"), None), t0);
    v.handle(Event::Up(bus("a"), false), t0);
    assert!(v.verdict(t0, secs(60)).is_err(), "its line is down");
}

#[test]
fn an_output_held_or_down_is_not_well_after_the_grace_only() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[output("scada"), bus("a")]);
    v.handle(Event::Up(output("scada"), true), t0);
    v.handle(Event::Up(bus("a"), true), t0);
    let held = Some("primary host offline".to_string());
    v.handle(Event::Held(output("scada"), held), t0 + secs(1));
    let within = t0 + secs(1) + OUTPUT_GRACE;
    let line = v.verdict(within, secs(3600)).expect("within the grace");
    assert!(
        line.contains("output/scada held: primary host offline"),
        "{line}"
    );
    let after = within + secs(1);
    let why = v.verdict(after, secs(3600)).unwrap_err();
    assert!(why.contains("output/scada held for 31 s"), "{why}");
    v.handle(Event::Held(output("scada"), None), after);
    assert!(v.verdict(after, secs(3600)).is_ok(), "well again");
    v.handle(Event::Up(output("scada"), false), after);
    let later = after + OUTPUT_GRACE + secs(5);
    let why = v.verdict(later, secs(3600)).unwrap_err();
    assert!(why.contains("output/scada disconnected for 35 s"), "{why}");
}

#[test]
fn an_outputs_last_error_and_spool_are_kept_for_the_page() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[output("json")]);
    v.handle(Event::Up(output("json"), false), t0);
    let refused = "connection refused".to_string();
    v.handle(
        Event::Failed(output("json"), refused, 1_700_000_000_000),
        t0,
    );
    v.handle(Event::Spool(output("json"), 12, 3400), t0);
    let down = v.loops(t0 + secs(4)).pop().unwrap();
    assert_eq!(down.down_for_ms, Some(4000));
    v.handle(Event::Up(output("json"), true), t0 + secs(5));
    let view = v.loops(t0 + secs(6)).pop().unwrap();
    assert_eq!(view.of, output("json"));
    assert!(view.up && view.down_for_ms.is_none());
    let (error, at) = view.last_error.unwrap();
    assert_eq!(
        (error.as_str(), at),
        ("connection refused", 1_700_000_000_000),
        "kept once up again"
    );
    assert_eq!((view.spool_messages, view.spool_bytes), (12, 3400));
}

#[test]
fn a_word_from_a_forgotten_loop_changes_nothing() {
    let t0 = Instant::now();
    let mut v = gateway(t0, &[bus("a"), bus("gone")]);
    v.handle(Event::Forgotten(bus("gone")), t0);
    v.handle(Event::Up(bus("gone"), true), t0);
    v.handle(Event::Up(bus("a"), true), t0);
    assert_eq!(v.loops(t0).len(), 1);
    assert!(v.status_line().starts_with("1/1 buses up"));
    assert!(!v.is_up(&bus("gone")));
}

#[test]
fn loops_are_named_by_kind_and_buses_come_first() {
    let t0 = Instant::now();
    let v = gateway(t0, &[output("a"), bus("z")]);
    let names: Vec<String> = v.loops(t0).iter().map(|l| l.of.to_string()).collect();
    assert_eq!(names, ["bus/z", "output/a"]);
}

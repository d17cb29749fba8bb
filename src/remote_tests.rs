//! Pushed configs, without a broker.

use std::path::Path;
use std::time::Duration;

use super::*;

fn config(extra: &str) -> Config {
    let text = format!(
        "[gateway]\nid = \"e1\"\n[mqtt]\nhost = \"127.0.0.1\"\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n{extra}"
    );
    Config::from_toml(&text, Path::new("x.toml"), Some(Default::default())).unwrap()
}

#[test]
fn a_push_is_an_id_and_the_config_text_and_nothing_else() {
    let p = parse(br#"{"id":"p1","toml":"[gateway]\n"}"#).unwrap();
    assert_eq!(
        (p.id.as_deref(), p.toml.as_str()),
        (Some("p1"), "[gateway]\n")
    );
    let (id, e) = parse(br#"{"id":"p2","toml":"x","extra":1}"#).unwrap_err();
    assert_eq!((id.as_deref(), e.code()), (Some("p2"), "bad_payload"));
    assert_eq!(parse(b"not json").unwrap_err().1.code(), "bad_payload");
    assert_eq!(
        parse(br#"{"id":"p3"}"#).unwrap_err().1.code(),
        "bad_payload"
    );
    let huge = vec![b' '; MAX_PUSH + 1];
    assert_eq!(parse(&huge).unwrap_err().1.code(), "too_large");
}

#[test]
fn secrets_and_trust_are_guarded_everything_else_is_not() {
    let old = config("");
    assert!(
        guarded_changes(
            &old,
            &config("[buses.l.devices.e]\nunit = 2\nmodel = \"yl67\"\n")
        )
        .is_empty()
    );
    let moved = config("").clone();
    let mut new = moved.clone();
    new.mqtt.host = "10.0.0.2".into();
    assert!(
        guarded_changes(&old, &new).is_empty(),
        "another broker is no secret"
    );
    let mut new = moved.clone();
    new.mqtt.password = Some(crate::config::Secret("x".into()));
    assert_eq!(
        guarded_changes(&old, &new),
        ["[mqtt] credentials or [mqtt.tls]"]
    );
    let mut new = old.clone();
    new.remote.config = true;
    assert_eq!(guarded_changes(&old, &new), ["[remote]"]);
}

#[test]
fn a_change_reaches_as_far_as_its_sections() {
    let old = config("");
    assert_eq!(
        reach(
            &old,
            &config("[buses.l.devices.e]\nunit = 2\nmodel = \"yl67\"\n")
        ),
        Reach::Reload
    );
    let mut new = old.clone();
    new.mqtt.port = 1884;
    assert_eq!(reach(&old, &new), Reach::Outputs);
    let mut new = old.clone();
    new.gateway.state_flush = Duration::from_secs(9);
    assert_eq!(reach(&old, &new), Reach::Restart);
}

#[test]
fn a_push_stays_when_its_connection_is_up_and_every_device_answered_again() {
    let now = Instant::now();
    let new = config("[buses.l.devices.e]\nunit = 2\nmodel = \"yl67\"\n");
    let before = ["d".to_string(), "gone".to_string()];
    let mut w = Watch::new(
        Some("p".into()),
        now,
        Duration::from_secs(60),
        "json",
        &before,
        &new,
    );
    assert_eq!(
        w.waiting.len(),
        1,
        "a device no longer configured is not waited for"
    );
    assert_eq!(w.verdict(now + Duration::from_secs(59), true), None);
    let end = now + Duration::from_secs(60);
    assert!(
        w.verdict(end, true)
            .unwrap()
            .unwrap_err()
            .contains("did not answer again: d")
    );
    w.online(&["d".into()]);
    assert_eq!(w.verdict(end, true), Some(Ok(())));
    assert!(w.verdict(end, false).unwrap().unwrap_err().contains("json"));
}

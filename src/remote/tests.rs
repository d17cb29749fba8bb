//! Pushed configs, without a broker.

use std::path::Path;
use std::time::Duration;

use super::*;
use tokio::time::Instant;

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
fn an_unsigned_push_may_change_operation_and_nothing_that_moves_trust() {
    use guard::{Signed, forbidden_changes};
    let old = config("");
    let more = config("[buses.l.devices.e]\nunit = 2\nmodel = \"yl67\"\n");
    assert!(forbidden_changes(&old, &more, Signed::No).is_empty());
    type Change = fn(&mut Config);
    let cases: [(&str, Change); 9] = [
        ("mqtt: host, port", |c| c.mqtt.port = 1884),
        ("mqtt: host, port", |c| c.mqtt.host = "10.0.0.2".into()),
        ("mqtt: credentials", |c| {
            c.mqtt.password = Some(crate::config::Secret("x".into()))
        }),
        ("mqtt: client_id", |c| c.mqtt.client_id = "other".into()),
        ("mqtt: topic_root", |c| c.mqtt.topic_root = "x".into()),
        ("mqtt: commands", |c| c.mqtt.commands = !c.mqtt.commands),
        ("[metrics]", |c| {
            c.metrics = Some(crate::config::MetricsEndpoint {
                listen: "0.0.0.0:9464".parse().unwrap(),
                token: None,
            })
        }),
        ("gateway.id", |c| c.gateway.id = "e2".into()),
        ("[remote]", |c| c.remote.config = !c.remote.config),
    ];
    for (named, change) in cases {
        let mut new = old.clone();
        change(&mut new);
        let forbidden = forbidden_changes(&old, &new, Signed::No);
        assert!(
            forbidden.iter().any(|f| f.starts_with(named)),
            "{named}: {forbidden:?}"
        );
        assert!(
            forbidden_changes(&old, &new, Signed::Yes).is_empty(),
            "{named} signed"
        );
    }
}

#[test]
fn a_password_from_a_file_never_follows_a_pushed_port() {
    use guard::{Signed, forbidden_changes};
    let mut old = config("");
    old.mqtt.password = Some(crate::config::Secret("from-a-file".into()));
    let mut new = old.clone();
    new.mqtt.port = 18830;
    let forbidden = forbidden_changes(&old, &new, Signed::No);
    assert_eq!(
        forbidden,
        ["mqtt: host, port, hosts or socket (where its credentials go)"]
    );
}

#[test]
fn a_new_output_is_allowed_only_on_the_gateways_own_connection() {
    use guard::{Signed, forbidden_changes};
    let old = config("");
    let same = config("[outputs.more]\nkind = \"json\"\ntopic_root = \"pulsegate/e1\"\n");
    let f = forbidden_changes(&old, &same, Signed::No);
    assert!(f.is_empty(), "{f:?}");
    let elsewhere = config("[outputs.more]\nkind = \"json\"\nhost = \"127.0.0.9\"\n");
    let f = forbidden_changes(&old, &elsewhere, Signed::No);
    assert!(
        f.iter()
            .any(|c| c.starts_with("outputs.more: host") && c.contains("a new output")),
        "{f:?}"
    );
    assert!(forbidden_changes(&old, &elsewhere, Signed::Yes).is_empty());
}

#[test]
fn the_state_directory_is_never_pushed_signed_or_not() {
    use guard::{Signed, forbidden_changes};
    let old = config("");
    let mut new = old.clone();
    new.gateway.state_dir = "/elsewhere".into();
    for signed in [Signed::No, Signed::Yes] {
        let f = forbidden_changes(&old, &new, signed);
        assert!(f[0].starts_with("gateway.state_dir"), "{f:?}");
    }
}

#[test]
fn a_signed_push_carries_serial_and_signature_together_and_an_id() {
    let p = parse(br#"{"id":"p1","toml":"x","serial":7,"signature":"c2ln"}"#).unwrap();
    assert_eq!(
        p.signed,
        Some(Signature {
            serial: 7,
            value: "c2ln".into()
        })
    );
    for bad in [
        &br#"{"id":"p1","toml":"x","serial":7}"#[..],
        br#"{"id":"p1","toml":"x","signature":"c2ln"}"#,
        br#"{"id":"p1","toml":"x","serial":-1,"signature":"c2ln"}"#,
        br#"{"toml":"x","serial":1,"signature":"c2ln"}"#,
    ] {
        assert_eq!(parse(bad).unwrap_err().1.code(), "bad_payload");
    }
}

#[test]
fn a_push_too_large_is_answered_with_its_id() {
    let toml = "#".repeat(100 * 1024);
    let payload = serde_json::json!({"id": "big", "toml": toml}).to_string();
    let (id, e) = parse(payload.as_bytes()).unwrap_err();
    assert_eq!((id.as_deref(), e.code()), (Some("big"), "too_large"));
}

#[test]
fn a_serial_must_grow() {
    assert_eq!(admit_serial(None, 0), Ok(()));
    assert_eq!(admit_serial(Some(4), 5), Ok(()));
    assert_eq!(
        admit_serial(Some(5), 5),
        Err(Refusal::Replayed { serial: 5, last: 5 })
    );
    assert_eq!(admit_serial(Some(5), 1).unwrap_err().code(), "replayed");
}

#[test]
fn a_start_resumes_a_watch_only_for_the_config_it_watched() {
    use watch::resume;
    let record = Record {
        id: Some("p".into()),
        connection: "json".into(),
        waiting: vec!["d".into()],
        previous: "x.toml.previous".into(),
        pushed_hash: "new".into(),
        previous_hash: Some("old".into()),
        announce: true,
        rollback: None,
    };
    assert_eq!(resume(&record, "new"), Resume::Watch { announce: true });
    assert_eq!(resume(&record, "old"), Resume::NeverApplied);
    assert_eq!(resume(&record, "edited"), Resume::Stale);
    let decided = Record {
        rollback: Some("d silent".into()),
        ..record
    };
    assert_eq!(resume(&decided, "new"), Resume::RollBack("d silent".into()));
    assert_eq!(
        resume(&decided, "old"),
        Resume::RolledBack("d silent".into())
    );
    assert_eq!(resume(&decided, "edited"), Resume::Stale);
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

#[test]
fn an_unsigned_push_may_add_to_a_plcs_register_map_but_not_move_it() {
    use guard::{Signed, forbidden_changes};
    let server = "[outputs.json]\nkind = \"json\"\n[outputs.plc]\nkind = \"modbus\"\n";
    let old = config(server);
    let more = config(&format!(
        "[buses.l.devices.e]\nunit = 2\nmodel = \"yl67\"\n{server}"
    ));
    assert!(forbidden_changes(&old, &more, Signed::No).is_empty());
    let moved = config(&format!("server_unit = 7\n{server}"));
    let f = forbidden_changes(&old, &moved, Signed::No);
    assert!(
        f.iter()
            .any(|c| c.contains("register map") && c.contains("d/")),
        "{f:?}"
    );
    assert!(forbidden_changes(&old, &moved, Signed::Yes).is_empty());
}

//! The dialer's choices, without a broker.

use super::*;
use std::time::Duration;

fn config(extra: &str) -> Mqtt {
    let text = format!(
        "[gateway]\nid = \"t\"\n[mqtt]\n{extra}\n[buses.l]\nhost = \"127.0.0.1\"\nport = 502\n[buses.l.devices.d]\nunit = 1\nmodel = \"yl67\"\n"
    );
    let env = Some(std::collections::HashMap::new());
    crate::config::Config::from_toml(&text, std::path::Path::new("x.toml"), env)
        .expect("config")
        .mqtt
}

fn silent() -> Failure {
    Failure::Other("Timeout".into())
}

fn wire_of(d: &Dialer) -> Wire {
    d.wire[d.at].0
}

#[test]
fn auto_speaks_mqtt_5_first_and_3_1_1_after_a_broker_that_never_answered_it() {
    let mut d = Dialer::new(&config("")).unwrap();
    assert_eq!(wire_of(&d), Wire::V5);
    let said = d.failed(&silent(), Instant::now());
    assert!(
        matches!(
            said[0],
            Said::Fallback {
                to: "MQTT 3.1.1",
                ..
            }
        ),
        "{said:?}"
    );
    assert_eq!(wire_of(&d), Wire::V311);
    assert!(matches!(d.options(), Options::V311(_)));
    assert_eq!(
        d.connected(),
        Some(Said::Speaks {
            broker: "127.0.0.1:1883".into(),
            protocol: "MQTT 3.1.1"
        })
    );
    // Once it answered, a broker restart is no reason to change the protocol.
    assert!(d.failed(&silent(), Instant::now()).is_empty());
    assert_eq!(wire_of(&d), Wire::V311);
}

#[test]
fn a_broker_that_refuses_the_connection_is_down_not_of_another_protocol() {
    let mut d = Dialer::new(&config("")).unwrap();
    let refused = Failure::Other("I/O: Connection refused (os error 111)".into());
    assert!(d.failed(&refused, Instant::now()).is_empty());
    assert_eq!(wire_of(&d), Wire::V5);
    let mut d = Dialer::new(&config("")).unwrap();
    assert!(
        !d.failed(&Failure::ProtocolRefused, Instant::now())
            .is_empty()
    );
    assert_eq!(wire_of(&d), Wire::V311, "CONNACK 0x01/0x84: 3.1.1 next");
}

#[test]
fn a_pinned_protocol_is_never_changed() {
    let mut d = Dialer::new(&config("protocol = \"5\"")).unwrap();
    assert!(d.failed(&silent(), Instant::now()).is_empty());
    assert_eq!(wire_of(&d), Wire::V5);
    assert_eq!(
        d.connected(),
        None,
        "nothing to say about a pinned protocol"
    );
}

#[test]
fn the_next_broker_after_failing_for_failover_after_and_round_robin() {
    let mut d = Dialer::new(&config(
        "hosts = [\"a:1883\", \"b:1884\"]\nfailover_after = \"30s\"\nprotocol = \"5\"",
    ))
    .unwrap();
    let t0 = Instant::now();
    assert_eq!(d.broker(), "a:1883");
    assert!(d.failed(&silent(), t0).is_empty());
    assert!(d.failed(&silent(), t0 + Duration::from_secs(29)).is_empty());
    let said = d.failed(&silent(), t0 + Duration::from_secs(30));
    assert!(
        matches!(&said[0], Said::MovedOn { to, .. } if to == "b:1884"),
        "{said:?}"
    );
    assert_eq!(d.broker(), "b:1884");
    // b fails for its own 30 s before the round comes back to a.
    assert!(d.failed(&silent(), t0 + Duration::from_secs(45)).is_empty());
    let said = d.failed(&silent(), t0 + Duration::from_secs(61));
    assert!(
        matches!(&said[0], Said::MovedOn { to, .. } if to == "a:1883"),
        "{said:?}"
    );
}

#[test]
fn a_connection_resets_the_failover_clock() {
    let mut d = Dialer::new(&config("hosts = [\"a:1\", \"b:2\"]\nprotocol = \"5\"")).unwrap();
    let t0 = Instant::now();
    d.failed(&silent(), t0);
    d.connected();
    assert!(d.failed(&silent(), t0 + Duration::from_secs(40)).is_empty());
    assert_eq!(d.broker(), "a:1");
}

#[test]
fn next_server_moves_at_once_and_not_with_one_broker() {
    let mut one = Dialer::new(&config("")).unwrap();
    assert_eq!(one.next_server(Instant::now(), "asked"), None);
    let mut two = Dialer::new(&config("hosts = [\"a:1\", \"b:2\"]")).unwrap();
    assert!(two.next_server(Instant::now(), "asked").is_some());
    assert_eq!(two.broker(), "b:2");
}

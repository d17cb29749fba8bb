use super::*;
use crate::publish::signed::{Origin, sign};
use crate::signing::SigningKey;

fn key() -> SigningKey {
    SigningKey::from_pem(&SigningKey::generate_pem().unwrap()).unwrap()
}

fn origin() -> Origin {
    Origin {
        record: "interval".into(),
        gateway: "g".into(),
        device: "m1".into(),
        channel: "a0".into(),
        period: "10s".into(),
    }
}

/// A signed interval record of seq `seq`, as `mosquitto_sub -v` prints it.
fn line(key: &SigningKey, seq: u64) -> String {
    let json = format!(
        r#"{{"start":"2026-12-04T06:00:00Z","end":"2026-12-04T06:00:10Z","delta":5,"total_start":{},"total_end":{},"status":"complete","seq":{seq}}}"#,
        seq * 5,
        seq * 5 + 5
    );
    format!(
        "pulsegate/m1/a0/interval/10s {}",
        sign(key, &origin(), json)
    )
}

fn marker(key: &SigningKey) -> String {
    format!(
        r#"pulsegate/gateway {{"boot":"b1","signing_key":"{}"}}"#,
        key.public_base64()
    )
}

#[test]
fn every_record_of_an_unbroken_capture_is_valid_with_the_key_of_the_marker() {
    let k = key();
    let lines = vec![
        line(&k, 1),
        marker(&k),
        line(&k, 2),
        line(&k, 2),
        line(&k, 3),
    ];
    let found = judge_all(None, &lines);
    assert!(matches!(found[0], Finding::Key(_)), "{found:?}");
    assert_eq!(
        found
            .iter()
            .filter(|f| matches!(f, Finding::Valid { .. }))
            .count(),
        4
    );
    assert!(!found.iter().any(Finding::is_bad), "{found:?}");
}

#[test]
fn a_skipped_seq_is_missing_and_a_changed_delta_is_tampered() {
    let k = key();
    let changed = line(&k, 2).replacen(r#""delta":5"#, r#""delta":6"#, 1);
    let lines = vec![line(&k, 1), changed, line(&k, 5)];
    let found = judge_all(Some(k.public()), &lines);
    let shown: Vec<String> = found.iter().map(|f| f.to_string()).collect();
    assert!(
        matches!(&found[1], Finding::Tampered { why, .. } if why.contains("delta=5")),
        "{shown:#?}"
    );
    assert_eq!(
        found[2],
        Finding::Missing {
            what: "m1/a0 interval 10s seq 5".into(),
            from: 2,
            to: 4
        },
        "the tampered one is not counted as received: {shown:#?}"
    );
    assert!(shown[2].starts_with("missing"), "{shown:#?}");
}

#[test]
fn lines_that_are_not_records_say_nothing_and_a_record_without_a_key_is_unchecked() {
    let k = key();
    let mut v = Verifier::new(None);
    assert!(v.line("pulsegate/m1/a0 {\"total\":3,\"seq\":1}").is_empty());
    assert!(v.line("not json").is_empty());
    assert!(matches!(v.line(&line(&k, 1))[..], [Finding::NoKey { .. }]));
    let unsigned = "pulsegate/m1/a0/billing {\"seq\":1}";
    let found = Verifier::new(Some(k.public())).line(unsigned);
    assert!(
        matches!(&found[..], [Finding::Tampered { .. }]),
        "{found:?}"
    );
}

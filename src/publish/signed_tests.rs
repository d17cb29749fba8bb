use super::*;

fn origin(record: &str, period: &str) -> Origin {
    Origin {
        record: record.into(),
        gateway: "plant-7".into(),
        device: "m1".into(),
        channel: "a0".into(),
        period: period.into(),
    }
}

fn object(json: &str) -> Map<String, Value> {
    match serde_json::from_str(json).unwrap() {
        Value::Object(m) => m,
        other => panic!("not an object: {other}"),
    }
}

fn key() -> SigningKey {
    SigningKey::from_pem(&SigningKey::generate_pem().unwrap()).unwrap()
}

const BILLING: &str = r#"{"start":"2026-12-04T06:00:00Z","end":"2026-12-05T23:00:00Z","total_start":100,"total_end":350,"delta":250,"value":0.25,"unit":"kWh","by_tariff":{"peak":200,"offpeak":50},"demand":{"value":1.8,"unit":"kW","start":"2026-12-04T07:00:00Z"},"status":"partial","seq":3}"#;

#[test]
fn the_text_names_who_then_the_fixed_fields_then_the_rest_by_name() {
    let text = text(&origin("billing", "daily"), &object(BILLING));
    assert_eq!(
        text,
        "pulsegate-record-v1\nrecord=billing\ngateway=plant-7\ndevice=m1\nchannel=a0\n\
         period=daily\nstart=2026-12-04T06:00:00Z\nend=2026-12-05T23:00:00Z\nseq=3\n\
         total_start=100\ntotal_end=350\ndelta=250\nunit=kWh\nstatus=partial\ntariff=\n\
         by_tariff.offpeak=50\nby_tariff.peak=200\ndemand.start=2026-12-04T07:00:00Z\n\
         demand.unit=kW\ndemand.value=1.8\nvalue=0.25\n"
    );
}

#[test]
fn a_line_break_in_a_value_cannot_make_a_line_of_its_own() {
    let json = object(r#"{"unit":"kWh\nstatus=complete","seq":1}"#);
    let text = text(&origin("interval", "15min"), &json);
    assert!(text.contains("unit=kWh\\nstatus=complete\n"), "{text}");
    assert_eq!(text.lines().filter(|l| l.starts_with("status=")).count(), 1);
}

#[test]
fn a_signed_record_keeps_its_fields_and_verifies_with_the_public_key() {
    let key = key();
    let signed = sign(&key, &origin("billing", "daily"), BILLING.to_string());
    assert!(
        signed.starts_with(&BILLING[..BILLING.len() - 1]),
        "{signed}"
    );
    let json = object(&signed);
    let bytes = STANDARD.decode(json["signed"].as_str().unwrap()).unwrap();
    assert_eq!(
        String::from_utf8(bytes).unwrap(),
        text(&origin("billing", "daily"), &object(BILLING))
    );
    let checked = check(&key.public(), Some("pulsegate/m1/a0/billing"), &json);
    assert_eq!(checked.verdict, Verdict::Valid);
    assert_eq!(checked.seq, Some(3));
    assert_eq!(checked.origin, Some(origin("billing", "daily")));
}

#[test]
fn a_changed_field_a_changed_text_another_key_or_another_topic_is_tampered() {
    let key = key();
    let signed = object(&sign(
        &key,
        &origin("billing", "daily"),
        BILLING.to_string(),
    ));
    let tampered = |json: &Map<String, Value>, topic: Option<&str>| {
        matches!(
            check(&key.public(), topic, json).verdict,
            Verdict::Tampered(_)
        )
    };
    let mut delta = signed.clone();
    delta.insert("delta".into(), 251.into());
    assert!(tampered(&delta, None), "a changed delta");
    let mut extra = signed.clone();
    extra.insert("note".into(), "x".into());
    assert!(tampered(&extra, None), "a field not signed");
    let mut text = signed.clone();
    let plain = STANDARD.decode(text["signed"].as_str().unwrap()).unwrap();
    let changed = String::from_utf8(plain)
        .unwrap()
        .replace("delta=250", "delta=251");
    text.insert("signed".into(), STANDARD.encode(changed).into());
    text.insert("delta".into(), 251.into());
    assert!(tampered(&text, None), "a changed signed text");
    assert!(
        tampered(&signed, Some("pulsegate/m2/a0/billing")),
        "another channel's topic"
    );
    let other = self::key();
    assert!(matches!(
        check(&other.public(), None, &signed).verdict,
        Verdict::Tampered(_)
    ));
    let mut bare = object(BILLING);
    bare.remove("signed");
    assert!(tampered(&bare, None), "not signed");
}

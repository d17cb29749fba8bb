use std::time::{Duration, SystemTime};

use super::*;
use crate::counter::Update;
use crate::event::Event;
use crate::profile::ChannelKind;
use crate::publish::sparkplug::command::{REBIRTH, dcmd};

fn shape(name: &str, kind: ChannelKind) -> ChannelShape {
    ChannelShape {
        name: name.into(),
        kind,
        freq: false,
        rpm: false,
        value_unit: None,
        writable: true,
        gauge: None,
        obis: None,
    }
}

fn setup(host: Option<&str>) -> Setup {
    Setup {
        topics: Topics::new("plant", "e1"),
        commands: crate::topics::Topics::new("pg/e1"),
        output: "sparkplug".into(),
        takes_commands: true,
        config_hash: "0123456789abcdef".into(),
        primary_host: host.map(str::to_string),
        qos: 1,
        devices: vec![
            (
                "press".into(),
                vec![
                    shape("a0", ChannelKind::Counter),
                    shape("enc0", ChannelKind::Encoder),
                ],
            ),
            ("pump".into(), vec![shape("a0", ChannelKind::Counter)]),
        ],
    }
}

fn reading(device: &str, channel: &str, total: i64, ms: u64) -> Reading {
    Reading {
        device: device.into(),
        channel: channel.into(),
        ts: SystemTime::UNIX_EPOCH + Duration::from_millis(ms),
        count: total,
        freq_hz: None,
        rpm: None,
        update: Update {
            delta: 1,
            total,
            seq: 1,
            rate_hz: Some(2.0),
            event: None,
        },
        after_seq: None,
        meter: None,
        kind: if channel.starts_with("enc") {
            ChannelKind::Encoder
        } else {
            ChannelKind::Counter
        },
        units: None,
        measured: None,
    }
}

fn decode(m: &Message) -> Payload {
    Payload::decode(&m.payload).unwrap()
}

/// What goes to the wire: each message through `outgoing`, as the MQTT task sends it.
fn wire(node: &mut Node, messages: &[Message], replay: bool) -> Vec<(String, Payload)> {
    messages
        .iter()
        .map(|m| {
            let bytes = node
                .outgoing(&m.topic, &m.payload, replay)
                .unwrap_or(m.payload.clone());
            (m.topic.clone(), Payload::decode(&bytes).unwrap())
        })
        .collect()
}

fn session(node: &mut Node, bd_seq: u8) -> Vec<Message> {
    node.will(bd_seq, 1);
    node.connected(1)
}

fn value_of<'a>(p: &'a Payload, name: &str) -> Option<&'a Value> {
    p.metrics
        .iter()
        .find(|m| m.name.as_deref() == Some(name))?
        .value
        .as_ref()
}

#[test]
fn the_will_and_the_nbirth_carry_the_same_bdseq() {
    let mut node = Node::new(setup(None));
    let (topic, will) = node.will(7, 1);
    assert_eq!(topic, "spBv1.0/plant/NDEATH/e1");
    let will = Payload::decode(&will).unwrap();
    assert_eq!(value_of(&will, BD_SEQ), Some(&Value::Long(7)));
    assert_eq!(will.seq, None, "a death has no seq");
    let births = node.connected(1);
    let nbirth = decode(&births[0]);
    assert_eq!(births[0].topic, "spBv1.0/plant/NBIRTH/e1");
    assert_eq!(value_of(&nbirth, BD_SEQ), Some(&Value::Long(7)));
    assert_eq!(value_of(&nbirth, REBIRTH), Some(&Value::Boolean(false)));
}

#[test]
fn births_number_from_zero_and_every_device_not_known_offline_is_born() {
    let mut node = Node::new(setup(None));
    node.event(
        &Output::DeviceStatus {
            device: "pump".into(),
            online: false,
        },
        1,
    );
    let births = session(&mut node, 0);
    let topics: Vec<&str> = births.iter().map(|m| m.topic.as_str()).collect();
    assert_eq!(
        topics,
        ["spBv1.0/plant/NBIRTH/e1", "spBv1.0/plant/DBIRTH/e1/press"]
    );
    let seqs: Vec<_> = births.iter().map(|m| decode(m).seq).collect();
    assert_eq!(seqs, [Some(0), Some(1)]);
    // The MQTT task may hand births to `outgoing` too: the numbers stay the same.
    node.disconnected();
    let births = session(&mut node, 1);
    let again: Vec<_> = wire(&mut node, &births, false)
        .into_iter()
        .map(|(_, p)| p.seq)
        .collect();
    assert_eq!(again, [Some(0), Some(1)]);
}

#[test]
fn a_dbirth_declares_every_metric_with_its_type_and_ddata_sends_aliases_only() {
    let mut node = Node::new(setup(None));
    let births = session(&mut node, 0);
    let dbirth = decode(&births[1]);
    let total = dbirth
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some("a0/Total"))
        .unwrap();
    assert_eq!(total.datatype, Some(datatype::UINT64));
    let enc = dbirth
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some("enc0/Total"))
        .unwrap();
    assert_eq!(
        enc.datatype,
        Some(datatype::INT64),
        "an encoder position is signed"
    );
    assert!(
        dbirth
            .metrics
            .iter()
            .all(|m| m.alias.is_some() && m.datatype.is_some())
    );
    assert_eq!(total.is_null, Some(true), "no value before the first poll");
    for w in ["a0/Clear", "a0/Preset", "enc0/Clear"] {
        assert!(value_of(&dbirth, w).is_some(), "{w} is writable");
    }
    let data = node.event(&Output::single(reading("press", "enc0", -5, 1000)), 2);
    let (topic, p) = wire(&mut node, &data, false).remove(0);
    assert_eq!(topic, "spBv1.0/plant/DDATA/e1/press");
    assert_eq!(p.seq, Some(3));
    assert_eq!(p.timestamp, Some(1000));
    let declared: HashSet<u64> = dbirth.metrics.iter().filter_map(|m| m.alias).collect();
    for m in &p.metrics {
        assert_eq!(m.name, None, "alias only");
        assert!(declared.contains(&m.alias.unwrap()), "{m:?} was declared");
        assert_eq!(m.timestamp, Some(1000));
        assert_eq!(m.is_historical, None);
    }
    let total_alias = enc.alias;
    let total = p.metrics.iter().find(|m| m.alias == total_alias).unwrap();
    assert_eq!(total.value, Some(Value::Long(-5i64 as u64)));
}

#[test]
fn seq_runs_over_every_message_of_the_node_and_wraps_after_255() {
    let mut node = Node::new(setup(None));
    let births = session(&mut node, 0);
    let mut seqs: Vec<u64> = births.iter().map(|m| decode(m).seq.unwrap()).collect();
    for i in 0..300 {
        let device = if i % 2 == 0 { "press" } else { "pump" };
        let out = node.event(&Output::single(reading(device, "a0", i, 5)), 5);
        seqs.extend(
            wire(&mut node, &out, false)
                .iter()
                .map(|(_, p)| p.seq.unwrap()),
        );
    }
    let expected: Vec<u64> = (0..seqs.len() as u64).map(|n| n % 256).collect();
    assert_eq!(seqs, expected);
}

#[test]
fn readings_spooled_while_away_go_out_after_the_rebirth_historical_with_their_times() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    node.disconnected();
    let spooled: Vec<Message> = (0..3)
        .flat_map(|i| {
            node.event(
                &Output::single(reading("press", "a0", i, 100 + i as u64)),
                9,
            )
        })
        .collect();
    assert!(
        spooled.iter().all(|m| m.topic.ends_with("DDATA/e1/press")),
        "no births while away"
    );
    let births = session(&mut node, 1);
    assert_eq!(births.len(), 3, "NBIRTH, press and pump");
    let sent = wire(&mut node, &spooled, true);
    let seqs: Vec<_> = sent.iter().map(|(_, p)| p.seq.unwrap()).collect();
    assert_eq!(seqs, [3, 4, 5], "after the births, no gap");
    for (i, (_, p)) in sent.iter().enumerate() {
        assert_eq!(p.timestamp, Some(100 + i as u64));
        assert!(
            p.metrics
                .iter()
                .all(|m| m.is_historical == Some(true) && m.name.is_none())
        );
    }
}

#[test]
fn an_alias_the_session_did_not_declare_goes_out_as_a_name() {
    let mut node = Node::new(setup(None));
    // Spooled by a run before this one, for a device this session has not born.
    node.event(
        &Output::DeviceStatus {
            device: "pump".into(),
            online: false,
        },
        1,
    );
    let old = node.event(&Output::single(reading("pump", "a0", 1, 1)), 1);
    node.event(
        &Output::DeviceStatus {
            device: "pump".into(),
            online: false,
        },
        1,
    );
    session(&mut node, 0);
    let (_, p) = wire(&mut node, &old, true).remove(0);
    assert!(
        p.metrics
            .iter()
            .all(|m| m.name.is_some() && m.alias.is_none())
    );
}

#[test]
fn a_device_going_offline_dies_and_is_born_again_when_it_answers() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let off = Output::DeviceStatus {
        device: "press".into(),
        online: false,
    };
    let death = node.event(&off, 5);
    assert_eq!(death.len(), 1);
    assert_eq!(death[0].topic, "spBv1.0/plant/DDEATH/e1/press");
    assert!(node.event(&off, 5).is_empty(), "one death");
    let back = node.event(&Output::single(reading("press", "a0", 3, 7)), 7);
    let topics: Vec<&str> = back.iter().map(|m| m.topic.as_str()).collect();
    assert_eq!(
        topics,
        [
            "spBv1.0/plant/DBIRTH/e1/press",
            "spBv1.0/plant/DDATA/e1/press"
        ]
    );
    let dbirth = decode(&back[0]);
    assert_eq!(
        value_of(&dbirth, "a0/Total"),
        Some(&Value::Long(3)),
        "with its values"
    );
}

#[test]
fn a_wrong_model_is_a_device_death() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let problem = Output::DeviceProblem {
        device: "pump".into(),
        status: "wrong_model",
    };
    let out = node.event(&problem, 5);
    assert_eq!(out[0].topic, "spBv1.0/plant/DDEATH/e1/pump");
}

#[test]
fn a_channel_changing_kind_is_born_again_with_its_new_type() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let mut r = reading("press", "a0", -2, 5);
    r.kind = ChannelKind::Encoder;
    let out = node.event(&Output::single(r), 5);
    assert_eq!(out.len(), 2);
    let dbirth = decode(&out[0]);
    let total = dbirth
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some("a0/Total"))
        .unwrap();
    assert_eq!(total.datatype, Some(datatype::INT64));
}

#[test]
fn ncmd_rebirth_births_everything_again_from_seq_zero_with_the_same_bdseq() {
    let mut node = Node::new(setup(None));
    session(&mut node, 4);
    let data = node.event(&Output::single(reading("press", "a0", 1, 5)), 5);
    wire(&mut node, &data, false);
    let ask = dcmd(vec![Metric::new(
        REBIRTH,
        None,
        datatype::BOOLEAN,
        Some(Value::Boolean(true)),
    )]);
    let r = node.received("spBv1.0/plant/NCMD/e1", &ask, 9);
    let (births, commands) = (r.messages, r.commands);
    assert!(commands.is_empty());
    let sent = wire(&mut node, &births, false);
    let topics: Vec<&str> = sent.iter().map(|(t, _)| t.as_str()).collect();
    assert_eq!(
        topics,
        [
            "spBv1.0/plant/NBIRTH/e1",
            "spBv1.0/plant/DBIRTH/e1/press",
            "spBv1.0/plant/DBIRTH/e1/pump"
        ]
    );
    assert_eq!(sent[0].1.seq, Some(0));
    assert_eq!(value_of(&sent[0].1, BD_SEQ), Some(&Value::Long(4)));
    let other_node = node.received("spBv1.0/plant/NCMD/e2", &ask, 9).messages;
    assert!(other_node.is_empty(), "another node's command");
}

#[test]
fn dcmd_writes_become_json_commands_on_the_channel_topic() {
    let mut node = Node::new(setup(None));
    let births = session(&mut node, 0);
    let preset_alias = decode(&births[1])
        .metrics
        .iter()
        .find(|m| m.name.as_deref() == Some("a0/Preset"))
        .and_then(|m| m.alias);
    let mut by_alias = Metric::new(
        "",
        preset_alias,
        datatype::INT64,
        Some(Value::Long(-7i64 as u64)),
    );
    by_alias.name = None;
    let write = dcmd(vec![
        Metric::new(
            "enc0/Clear",
            None,
            datatype::BOOLEAN,
            Some(Value::Boolean(true)),
        ),
        by_alias,
    ]);
    let r = node.received("spBv1.0/plant/DCMD/e1/press", &write, 9);
    let (msgs, commands) = (r.messages, r.commands);
    assert!(msgs.is_empty());
    let got: Vec<(&str, &[u8])> = commands
        .iter()
        .map(|c| (c.topic.as_str(), &c.payload[..]))
        .collect();
    assert_eq!(
        got,
        [
            ("pg/e1/press/enc0/cmd", &br#"{"op":"clear"}"#[..]),
            ("pg/e1/press/a0/cmd", &br#"{"op":"preset","value":-7}"#[..]),
        ]
    );
    assert!(commands.iter().all(|c| !c.retain));
}

#[test]
fn a_dcmd_with_one_bad_write_is_refused_whole() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let topic = "spBv1.0/plant/DCMD/e1/press";
    let clear = Metric::new(
        "a0/Clear",
        None,
        datatype::BOOLEAN,
        Some(Value::Boolean(true)),
    );
    for bad in [
        Metric::new("a0/Total", None, datatype::UINT64, Some(Value::Long(0))),
        Metric::new(
            "a0/Preset",
            None,
            datatype::DOUBLE,
            Some(Value::Double(1.5)),
        ),
        Metric::new(
            "a0/Clear",
            None,
            datatype::STRING,
            Some(Value::String("yes".into())),
        ),
    ] {
        let commands = node
            .received(topic, &dcmd(vec![clear.clone(), bad.clone()]), 9)
            .commands;
        assert!(commands.is_empty(), "{bad:?}");
    }
    let commands = node
        .received(topic, b"\xff\xff\xff not protobuf", 9)
        .commands;
    assert!(commands.is_empty());
    let commands = node
        .received("spBv1.0/plant/DCMD/e1/ghost", &dcmd(vec![clear]), 9)
        .commands;
    assert!(commands.is_empty(), "a device the node does not have");
    let many = vec![
        Metric::new(
            "a0/Clear",
            None,
            datatype::BOOLEAN,
            Some(Value::Boolean(false))
        );
        65
    ];
    let commands = node.received(topic, &dcmd(many), 9).commands;
    assert!(commands.is_empty());
}

#[test]
fn with_a_primary_host_births_wait_for_its_state_online_and_follow_it() {
    let mut node = Node::new(setup(Some("scada")));
    assert!(
        node.subscriptions(true)
            .contains(&"spBv1.0/STATE/scada".to_string())
    );
    assert!(
        session(&mut node, 0).is_empty(),
        "the host is not online yet"
    );
    let state = "spBv1.0/STATE/scada";
    assert!(node.holding(), "connected, waiting: the outbox is held");
    let held = node.event(&Output::single(reading("press", "a0", 1, 3)), 3);
    assert!(
        decode(&held[0])
            .metrics
            .iter()
            .all(|m| m.is_historical == Some(true)),
        "made while held: history"
    );
    let births = node.received(state, br#"{"online":true,"timestamp":5}"#, 9);
    assert_eq!(births.at_once.len(), 3, "at once, ahead of what was held");
    assert!(!node.holding());
    let sent = wire(&mut node, &held, false);
    assert_eq!(sent[0].1.seq, Some(3), "the held data after the births");
    let again = node.received(state, br#"{"online":true,"timestamp":6}"#, 9);
    assert!(again.at_once.is_empty() && again.messages.is_empty());
    let gone = node.received(state, br#"{"online":false,"timestamp":7}"#, 9);
    let topics: Vec<&str> = gone.at_once.iter().map(|m| m.topic.as_str()).collect();
    assert_eq!(topics, ["spBv1.0/plant/NDEATH/e1"], "a death, then quiet");
    assert!(node.holding());
    let back = node.received(state, br#"{"online":true,"timestamp":8}"#, 9);
    assert_eq!(back.at_once.len(), 3, "born again when the host is back");
    assert_eq!(decode(&back.at_once[0]).seq, Some(0));
    assert!(node.received(state, b"garbage", 9).at_once.is_empty());
}

#[test]
fn events_and_writes_show_up_in_the_next_ddata() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let mut r = reading("press", "a0", 0, 5);
    r.update.event = Some(Event::Cleared);
    let out = node.event(&Output::single(r), 5);
    let p = decode(&out[0]);
    assert_eq!(
        value_of(&p, "a0/Event"),
        Some(&Value::String("cleared".into()))
    );
}

#[test]
fn a_message_offered_again_after_the_client_refused_it_keeps_its_number() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let data = node.event(&Output::single(reading("press", "a0", 1, 5)), 5);
    let first = node
        .outgoing(&data[0].topic, &data[0].payload, false)
        .unwrap();
    node.unsent();
    let again = node
        .outgoing(&data[0].topic, &data[0].payload, false)
        .unwrap();
    assert_eq!(first, again);
    let next = node.event(&Output::single(reading("press", "a0", 2, 6)), 6);
    let (_, p) = wire(&mut node, &next, false).remove(0);
    assert_eq!(
        p.seq,
        Some(4),
        "no gap: NBIRTH 0, DBIRTHs 1 and 2, then 3 and 4"
    );
}

/// Two answers can be byte for byte the same (same values, same millisecond): each is a
/// message of its own and takes its own number.
#[test]
fn two_identical_messages_sent_one_after_the_other_take_two_numbers() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let data = node.event(&Output::single(reading("press", "a0", 1, 5)), 5);
    let first = node
        .outgoing(&data[0].topic, &data[0].payload, false)
        .unwrap();
    let second = node
        .outgoing(&data[0].topic, &data[0].payload, false)
        .unwrap();
    let seq = |b: &Bytes| super::super::proto::Payload::decode(b).unwrap().seq;
    assert_eq!((seq(&first), seq(&second)), (Some(3), Some(4)));
}

#[test]
fn the_readings_of_one_poll_are_one_ddata() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let poll = Output::DeviceReadings {
        device: "press".into(),
        readings: vec![
            reading("press", "a0", 1, 9),
            reading("press", "enc0", -1, 9),
        ],
    };
    let out = node.event(&poll, 9);
    assert_eq!(out.len(), 1);
    let p = decode(&out[0]);
    assert!(value_of(&p, "a0/Total").is_some() && value_of(&p, "enc0/Total").is_some());
    assert_eq!(p.timestamp, Some(9));
}

/// A rebirth asked for while readings wait in the outbox goes behind them: the readings are
/// numbered on as before, then the NBIRTH starts at 0 and the DBIRTHs follow it, with no gap
/// and no number taken twice (a host that saw `seq` 3 right after 91 asked for a rebirth).
#[test]
fn a_rebirth_behind_waiting_readings_is_numbered_when_it_leaves() {
    let mut node = Node::new(setup(None));
    session(&mut node, 0);
    let sent: Vec<Message> = (0..3)
        .flat_map(|i| node.event(&Output::single(reading("press", "a0", i, 5 + i as u64)), 5))
        .collect();
    let on_the_wire: Vec<u64> = wire(&mut node, &sent, false)
        .iter()
        .map(|(_, p)| p.seq.unwrap())
        .collect();
    assert_eq!(on_the_wire, [3, 4, 5]);
    let waiting: Vec<Message> = (0..5)
        .flat_map(|i| {
            node.event(
                &Output::single(reading("press", "a0", i, 10 + i as u64)),
                10,
            )
        })
        .collect();
    let ask = dcmd(vec![Metric::new(
        REBIRTH,
        None,
        datatype::BOOLEAN,
        Some(Value::Boolean(true)),
    )]);
    let births = node.received("spBv1.0/plant/NCMD/e1", &ask, 99).messages;
    let after = node.event(&Output::single(reading("press", "a0", 9, 100)), 100);
    let mut all = waiting;
    all.extend(births);
    all.extend(after);
    let seqs: Vec<u64> = wire(&mut node, &all, false)
        .iter()
        .map(|(_, p)| p.seq.unwrap())
        .collect();
    assert_eq!(seqs, [6, 7, 8, 9, 10, 0, 1, 2, 3]);
}

#[test]
fn a_channel_named_by_obis_says_it_as_a_property_of_its_total_and_value_in_the_dbirth() {
    use crate::publish::sparkplug::metrics::{Aliases, OBIS_PROPERTY, birth};
    use crate::publish::sparkplug::proto::PropertyKind;
    let mut named = shape("a0", ChannelKind::Counter);
    named.value_unit = Some(Some("kWh".into()));
    named.obis = Some("1-0:1.8.0".into());
    let metrics = birth(
        "press",
        &[named],
        &Default::default(),
        &mut Aliases::default(),
    );
    let obis_of = |name: &str| {
        let m = metrics.iter().find(|m| m.name.as_deref() == Some(name))?;
        let set = m.properties.as_ref()?;
        let at = set.keys.iter().position(|k| k == OBIS_PROPERTY)?;
        match &set.values[at].value {
            Some(PropertyKind::String(s)) => Some(s.clone()),
            _ => None,
        }
    };
    assert_eq!(obis_of("a0/Total").as_deref(), Some("1-0:1.8.0"));
    assert_eq!(obis_of("a0/Value").as_deref(), Some("1-0:1.8.0"));
    assert_eq!(obis_of("a0/Delta"), None, "a delta is not the register");
}

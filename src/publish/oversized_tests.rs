//! A message larger than the gateway takes costs nothing but itself: rumqttc's reader (patched,
//! vendor/rumqttc/src/oversized.rs) skips it as its bytes stream in, the state acknowledges it,
//! and the session reports it as [`Event::TooLarge`], on both protocols.

use bytes::{BufMut, BytesMut};
use tokio::io::{AsyncReadExt, AsyncWriteExt};
use tokio_util::codec::Decoder;

use super::session::{Event, Options, Settings};
use crate::config::MqttProtocol;

/// A PUBLISH at QoS 1 (v5: with an empty property list), retained, on the wire.
fn publish(v5: bool, topic: &str, pkid: u16, payload_len: usize) -> Vec<u8> {
    let mut body = BytesMut::new();
    body.put_u16(topic.len() as u16);
    body.put_slice(topic.as_bytes());
    body.put_u16(pkid);
    if v5 {
        body.put_u8(0);
    }
    body.put_bytes(b'x', payload_len);
    let mut packet = vec![0x33];
    let mut len = body.len();
    loop {
        let byte = (len % 128) as u8;
        len /= 128;
        packet.push(if len > 0 { byte | 0x80 } else { byte });
        if len == 0 {
            break;
        }
    }
    packet.extend_from_slice(&body);
    packet
}

const TOPIC: &str = "pulsegate/test/press/enc0/cmd";
const PINGRESP: [u8; 2] = [0xd0, 0x00];

/// Feeds `wire` to `codec` the way tokio's `Framed` does, cut into reads of 3 bytes for the
/// first 64 (the head split everywhere) and 4 KiB after; returns what it decoded and the most
/// bytes it ever held.
fn read_in_pieces<C: Decoder>(codec: &mut C, wire: &[u8]) -> (Vec<C::Item>, usize)
where
    C::Error: std::fmt::Debug,
{
    let (mut buf, mut frames, mut held, mut at) = (BytesMut::new(), Vec::new(), 0, 0);
    while at < wire.len() {
        let n = if at < 64 { 3 } else { 4096 }.min(wire.len() - at);
        buf.extend_from_slice(&wire[at..at + n]);
        at += n;
        held = held.max(buf.len());
        while let Some(frame) = codec.decode(&mut buf).expect("no error") {
            frames.push(frame);
        }
    }
    assert!(buf.is_empty(), "every byte read");
    (frames, held)
}

#[test]
fn a_publish_over_the_limit_is_skipped_in_bounded_memory_and_the_next_packets_are_read() {
    let mut wire = publish(false, TOPIC, 7, 300 * 1024);
    let size = wire.len();
    wire.extend(publish(false, TOPIC, 8, 10));
    wire.extend(PINGRESP);
    let mut codec = rumqttc::SkipOversized::new(rumqttc::mqttbytes::v4::Codec {
        max_incoming_size: 256 * 1024,
        max_outgoing_size: 256 * 1024,
    });
    let (frames, held) = read_in_pieces(&mut codec, &wire);
    assert!(
        held <= 8 * 1024,
        "held {held} bytes: never the whole packet"
    );
    let [first, second, third] = &frames[..] else {
        panic!("three frames: {frames:?}");
    };
    let rumqttc::Frame::Oversized(o) = first else {
        panic!("the large one is named, not read: {first:?}");
    };
    assert_eq!(
        (o.size, o.topic.as_str(), o.qos, o.pkid, o.retain),
        (size, TOPIC, rumqttc::QoS::AtLeastOnce, 7, true)
    );
    assert!(
        matches!(second, rumqttc::Frame::Packet(rumqttc::Packet::Publish(p)) if p.pkid == 8 && p.payload.len() == 10)
    );
    assert!(matches!(
        third,
        rumqttc::Frame::Packet(rumqttc::Packet::PingResp)
    ));
}

#[test]
fn over_mqtt_5_a_publish_over_the_limit_is_skipped_the_same_way() {
    use rumqttc::v5::mqttbytes::v5::{Codec, Packet};
    let mut wire = publish(true, TOPIC, 9, 300 * 1024);
    let size = wire.len();
    wire.extend(publish(true, TOPIC, 10, 10));
    let mut codec = rumqttc::SkipOversized::new(Codec {
        max_incoming_size: Some(256 * 1024),
        max_outgoing_size: None,
    });
    let (frames, held) = read_in_pieces(&mut codec, &wire);
    assert!(
        held <= 8 * 1024,
        "held {held} bytes: never the whole packet"
    );
    assert!(
        matches!(&frames[..], [rumqttc::Frame::Oversized(o), rumqttc::Frame::Packet(Packet::Publish(p))]
            if o.pkid == 9 && o.size == size && o.topic == TOPIC && p.pkid == 10),
        "{frames:?}"
    );
}

#[test]
fn a_packet_over_the_limit_that_is_no_publish_is_still_an_error() {
    // A SUBACK claiming 304 KiB: only a broker breaking the protocol sends that.
    let mut wire = BytesMut::from(&[0x90u8, 0x80, 0x80, 0x13, 0x00, 0x01][..]);
    let mut codec = rumqttc::SkipOversized::new(rumqttc::mqttbytes::v4::Codec {
        max_incoming_size: 256 * 1024,
        max_outgoing_size: 256 * 1024,
    });
    assert!(codec.decode(&mut wire).is_err());
}

#[test]
fn the_state_acknowledges_a_skipped_publish_so_the_broker_does_not_hold_it_in_flight() {
    let dropped = |qos| rumqttc::Oversized {
        size: 300_000,
        topic: TOPIC.into(),
        qos,
        pkid: 7,
        retain: true,
    };
    let mut v4 = rumqttc::MqttState::new(10, true);
    let ack = v4.handle_oversized(dropped(rumqttc::QoS::AtLeastOnce));
    assert!(
        matches!(ack, Ok(Some(rumqttc::Packet::PubAck(a))) if a.pkid == 7),
        "acknowledged even with manual acks: the user never sees it"
    );
    assert!(matches!(
        v4.events.front(),
        Some(rumqttc::Event::Dropped(o)) if o.pkid == 7
    ));
    let mut v5 = rumqttc::v5::MqttState::new(10, false);
    let ack = v5.handle_oversized(dropped(rumqttc::QoS::ExactlyOnce));
    use rumqttc::v5::mqttbytes::v5::{Packet, PubRecReason};
    assert!(
        matches!(ack, Ok(Some(Packet::PubRec(r))) if r.pkid == 7 && r.reason == PubRecReason::ImplementationSpecificError),
        "a refusing PUBREC ends the QoS 2 flow"
    );
}

/// A broker on loopback that takes one CONNECT, answers `connack`, writes `wire` in pieces and
/// hands over the first bytes the client sends after that (its acknowledgements); it keeps the
/// connection open until the client closes it.
async fn scripted_broker(
    connack: &'static [u8],
    wire: Vec<u8>,
) -> (u16, tokio::sync::oneshot::Receiver<Vec<u8>>) {
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let port = listener.local_addr().unwrap().port();
    let (acks, acked) = tokio::sync::oneshot::channel();
    tokio::spawn(async move {
        let (mut s, _) = listener.accept().await.unwrap();
        let mut buf = vec![0u8; 1024];
        let _connect = s.read(&mut buf).await.unwrap();
        s.write_all(connack).await.unwrap();
        for piece in wire.chunks(1000) {
            s.write_all(piece).await.unwrap();
        }
        let n = s.read(&mut buf).await.unwrap();
        let _ = acks.send(buf[..n].to_vec());
        while s.read(&mut buf).await.is_ok_and(|n| n > 0) {}
    });
    (port, acked)
}

/// The gateway's own session on `protocol` against the scripted broker: the large message is
/// reported and acknowledged, and a message of 256 KiB (a pushed config as large as one may be)
/// behind it arrives whole on the same connection.
async fn a_large_message_costs_only_itself(protocol: MqttProtocol) {
    let v5 = protocol == MqttProtocol::V5;
    let connack: &'static [u8] = if v5 {
        &[0x20, 3, 0, 0, 0]
    } else {
        &[0x20, 2, 0, 0]
    };
    let mut wire = publish(v5, TOPIC, 7, 300 * 1024);
    let size = wire.len();
    wire.extend(publish(v5, "pulsegate/test/config/set", 8, 256 * 1024));
    let (port, acked) = scripted_broker(connack, wire).await;
    let (_client, mut events) = Options::new(Settings {
        protocol,
        client_id: "t",
        host: "127.0.0.1",
        port,
        keep_alive: std::time::Duration::from_secs(30),
        max_incoming: super::session::MAX_PACKET,
        inflight: 10,
        login: None,
        transport: None,
    })
    .connect(None, 10);
    let mut seen = Vec::new();
    while !matches!(seen.last(), Some(Event::Received(_))) {
        let polled = tokio::time::timeout(std::time::Duration::from_secs(5), events.poll());
        seen.push(
            polled
                .await
                .expect("in time")
                .expect("the connection stays up"),
        );
    }
    assert!(
        seen.iter().any(
            |e| matches!(e, Event::TooLarge { topic, size: s } if topic == TOPIC && *s == size)
        ),
        "{seen:?}"
    );
    let Some(Event::Received(config)) = seen.last() else {
        unreachable!("the loop ends at a message")
    };
    assert_eq!(
        config.payload.len(),
        256 * 1024,
        "a 256 KiB message is taken"
    );
    let ack = acked.await.expect("acknowledged");
    assert_eq!((ack[0], &ack[2..4]), (0x40, &[0u8, 7][..]), "PUBACK 7");
}

#[tokio::test]
async fn over_mqtt_3_1_1_a_message_larger_than_the_gateway_takes_costs_only_itself() {
    a_large_message_costs_only_itself(MqttProtocol::V311).await;
}

#[tokio::test]
async fn over_mqtt_5_a_message_larger_than_the_gateway_takes_costs_only_itself() {
    a_large_message_costs_only_itself(MqttProtocol::V5).await;
}

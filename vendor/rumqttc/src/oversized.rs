//! pulsegate patch (see PULSEGATE-PATCH.md): an incoming PUBLISH larger than the client's
//! maximum incoming packet size is skipped instead of ending the connection.
//!
//! Upstream's codecs refuse such a packet with `PayloadSizeLimitExceeded`, an error that ends
//! the connection. A retained message on a subscribed topic then comes back at every reconnect,
//! and keeps the client off its broker for as long as it stays there; anyone who may write one
//! topic the client subscribes can do that. Here the reader takes the packet's fixed header,
//! topic and packet id (at most 5 + 2 + 65535 + 2 bytes), discards the rest as it streams in
//! (it never holds more than what one read brought), and hands the event loop an [`Oversized`]
//! notice once the last byte is gone; the state then acknowledges the packet id and reports it.
//!
//! Only a PUBLISH is skipped: it carries what another client wrote. Any other packet over the
//! limit is still the error it was upstream: a broker that sends an oversized acknowledgement
//! breaks the protocol, and skipping it would leave the session's state wrong.

use bytes::{Buf, BytesMut};
use tokio_util::codec::{Decoder, Encoder};

use crate::mqttbytes::QoS;

/// An incoming PUBLISH larger than the client takes, dropped unread.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Oversized {
    /// Its size on the wire, fixed header included.
    pub size: usize,
    /// Its topic (not UTF-8: lossily converted).
    pub topic: String,
    pub qos: QoS,
    /// Its packet id (0 at QoS 0).
    pub pkid: u16,
    pub retain: bool,
}

/// What the reader hands the event loop: a packet, or the notice of one it dropped.
#[derive(Debug)]
pub enum Frame<P> {
    Packet(P),
    Oversized(Oversized),
}

/// A codec's "packet larger than the maximum incoming size" error, on either protocol.
pub trait TooLarge {
    fn too_large(&self) -> bool;
}

impl TooLarge for crate::mqttbytes::Error {
    fn too_large(&self) -> bool {
        matches!(self, Self::PayloadSizeLimitExceeded(_))
    }
}

impl TooLarge for crate::v5::mqttbytes::Error {
    fn too_large(&self) -> bool {
        matches!(self, Self::PayloadSizeLimitExceeded { .. })
    }
}

/// A codec that skips incoming PUBLISH packets its inner codec refuses as too large (see the
/// module's doc); everything else, both ways, is the inner codec's.
#[derive(Debug, Clone)]
pub struct SkipOversized<C> {
    pub codec: C,
    skipping: Option<Skipping>,
}

/// A packet being discarded: the bytes of it still to come, and the notice for when they have.
#[derive(Debug, Clone)]
struct Skipping {
    left: usize,
    notice: Oversized,
}

impl<C> SkipOversized<C> {
    pub fn new(codec: C) -> Self {
        SkipOversized {
            codec,
            skipping: None,
        }
    }

    /// Drops what of the skipped packet is in `src`; its notice once the last byte is gone.
    fn discard(&mut self, src: &mut BytesMut) -> Option<Oversized> {
        let skipping = self.skipping.as_mut()?;
        let n = skipping.left.min(src.len());
        src.advance(n);
        skipping.left -= n;
        if skipping.left > 0 {
            return None;
        }
        self.skipping.take().map(|s| s.notice)
    }
}

impl<C> Decoder for SkipOversized<C>
where
    C: Decoder,
    C::Error: TooLarge,
{
    type Item = Frame<C::Item>;
    type Error = C::Error;

    fn decode(&mut self, src: &mut BytesMut) -> Result<Option<Self::Item>, Self::Error> {
        if self.skipping.is_none() {
            match self.codec.decode(src) {
                Ok(packet) => return Ok(packet.map(Frame::Packet)),
                Err(e) if e.too_large() => match head(src) {
                    Head::Publish(skipping) => self.skipping = Some(skipping),
                    Head::NeedMore(n) => {
                        src.reserve(n);
                        return Ok(None);
                    }
                    Head::NotPublish => return Err(e),
                },
                Err(e) => return Err(e),
            }
        }
        Ok(self.discard(src).map(Frame::Oversized))
    }
}

impl<C: Encoder<I>, I> Encoder<I> for SkipOversized<C> {
    type Error = C::Error;

    fn encode(&mut self, item: I, dst: &mut BytesMut) -> Result<(), Self::Error> {
        self.codec.encode(item, dst)
    }
}

/// What the start of a packet too large to take says of it.
#[derive(Debug)]
enum Head {
    /// A PUBLISH: skip it.
    Publish(Skipping),
    /// Its topic and packet id need this many more bytes.
    NeedMore(usize),
    /// Another packet type, or a PUBLISH whose head contradicts its length.
    NotPublish,
}

/// Reads the fixed header, topic and packet id of the packet at the start of `src`.
fn head(src: &[u8]) -> Head {
    let Some(&byte1) = src.first() else {
        return Head::NeedMore(2);
    };
    let (mut remaining, mut at) = (0usize, 1);
    loop {
        let Some(&b) = src.get(at) else {
            return Head::NeedMore(1);
        };
        remaining |= usize::from(b & 0x7F) << (7 * (at - 1));
        at += 1;
        if b & 0x80 == 0 {
            break;
        }
        if at > 4 {
            return Head::NotPublish;
        }
    }
    if byte1 >> 4 != 3 {
        return Head::NotPublish;
    }
    let qos = match (byte1 >> 1) & 0b11 {
        0 => QoS::AtMostOnce,
        1 => QoS::AtLeastOnce,
        2 => QoS::ExactlyOnce,
        _ => return Head::NotPublish,
    };
    let body = &src[at..];
    if body.len() < 2 {
        return Head::NeedMore(2 - body.len());
    }
    let topic_len = usize::from(u16::from_be_bytes([body[0], body[1]]));
    let id_len = if qos == QoS::AtMostOnce { 0 } else { 2 };
    let head_len = 2 + topic_len + id_len;
    if head_len > remaining {
        return Head::NotPublish;
    }
    if body.len() < head_len {
        return Head::NeedMore(head_len - body.len());
    }
    let topic = String::from_utf8_lossy(&body[2..2 + topic_len]).into_owned();
    let pkid = match id_len {
        0 => 0,
        _ => u16::from_be_bytes([body[2 + topic_len], body[3 + topic_len]]),
    };
    let size = at + remaining;
    Head::Publish(Skipping {
        left: size,
        notice: Oversized {
            size,
            topic,
            qos,
            pkid,
            retain: byte1 & 1 == 1,
        },
    })
}

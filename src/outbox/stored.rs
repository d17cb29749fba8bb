//! An [`Entry`] as a spool file keeps it: one JSON object a line.
//!
//! The payload is kept in whichever form is smaller: text (`"payload":"…"`, readable, and what
//! every earlier version wrote for UTF-8 payloads) or base64 (`"payload_b64":"…"`, for binary
//! payloads such as protobuf, 4 characters for 3 bytes). Earlier versions wrote binary payloads
//! as an array of byte values (`"payload":[8,1,…]`, 3–4 characters a byte); such lines are
//! still read.

use base64::Engine;
use bytes::Bytes;
use serde::de::Error as _;
use serde::ser::SerializeStruct;
use serde::{Deserialize, Deserializer, Serialize, Serializer};

use super::Entry;

const B64: base64::engine::GeneralPurpose = base64::engine::general_purpose::STANDARD;

/// Characters `text` takes as a JSON string's contents (escapes included).
fn escaped_len(text: &str) -> usize {
    text.bytes()
        .map(|b| match b {
            b'"' | b'\\' | b'\n' | b'\r' | b'\t' | 0x08 | 0x0c => 2,
            0..0x20 => 6,
            _ => 1,
        })
        .sum()
}

/// Whether `payload` is kept as text: it is UTF-8 and no longer so than as base64 (whose key,
/// `payload_b64`, is 4 characters longer).
fn as_text(payload: &[u8]) -> Option<&str> {
    let text = std::str::from_utf8(payload).ok()?;
    (escaped_len(text) <= payload.len().div_ceil(3) * 4 + 4).then_some(text)
}

impl Serialize for Entry {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let fields = 5 + usize::from(self.correlation.is_some());
        let mut st = s.serialize_struct("Entry", fields)?;
        st.serialize_field("seq", &self.seq)?;
        st.serialize_field("topic", &self.topic)?;
        match as_text(&self.payload) {
            Some(text) => st.serialize_field("payload", text)?,
            None => st.serialize_field("payload_b64", &B64.encode(&self.payload))?,
        }
        st.serialize_field("qos", &self.qos)?;
        st.serialize_field("retain", &self.retain)?;
        if let Some(c) = &self.correlation {
            st.serialize_field("correlation", c)?;
        }
        st.end()
    }
}

/// A payload as earlier versions wrote it under `payload`: text, or an array of byte values.
#[derive(Deserialize)]
#[serde(untagged)]
enum Legacy {
    Text(String),
    Raw(Vec<u8>),
}

/// A line as read, before its payload is checked.
#[derive(Deserialize)]
struct Line {
    seq: u64,
    topic: String,
    #[serde(default)]
    payload: Option<Legacy>,
    #[serde(default)]
    payload_b64: Option<String>,
    qos: u8,
    retain: bool,
    #[serde(default)]
    correlation: Option<Vec<u8>>,
}

impl<'de> Deserialize<'de> for Entry {
    fn deserialize<D: Deserializer<'de>>(d: D) -> Result<Entry, D::Error> {
        let line = Line::deserialize(d)?;
        let payload = match (line.payload, line.payload_b64) {
            (Some(Legacy::Text(t)), None) => Bytes::from(t),
            (Some(Legacy::Raw(r)), None) => Bytes::from(r),
            (None, Some(b)) => Bytes::from(B64.decode(b).map_err(D::Error::custom)?),
            _ => return Err(D::Error::custom("needs one of payload and payload_b64")),
        };
        Ok(Entry {
            seq: line.seq,
            topic: line.topic,
            payload,
            qos: line.qos,
            retain: line.retain,
            correlation: line.correlation,
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn entry(payload: &[u8]) -> Entry {
        Entry {
            seq: 123_456,
            topic: "spBv1.0/plant/DDATA/edge-01/press1".into(),
            payload: Bytes::copy_from_slice(payload),
            qos: 1,
            retain: false,
            correlation: None,
        }
    }

    fn line(e: &Entry) -> String {
        serde_json::to_string(e).unwrap()
    }

    /// Bytes that look like a protobuf payload: field tags, small numbers, high bytes.
    fn binary(n: usize) -> Vec<u8> {
        (0..n)
            .map(|i| [0x08, 0x01, 0x12, 0x9a, 0xff, 0x00, 0x20][i % 7] ^ (i as u8 & 0x40))
            .collect()
    }

    #[test]
    fn a_binary_payload_of_60_to_200_bytes_adds_at_most_one_and_a_half_times_its_size_to_its_line()
    {
        for n in [60, 61, 62, 100, 128, 200] {
            let e = entry(&binary(n));
            let cost = line(&e).len() - line(&entry(b"")).len();
            assert!(
                cost as f64 <= 1.5 * n as f64,
                "{n} bytes take {cost}: {}",
                line(&e)
            );
            assert_eq!(serde_json::from_str::<Entry>(&line(&e)).unwrap(), e);
        }
    }

    #[test]
    fn a_payload_of_control_characters_is_kept_as_base64_though_it_is_utf8() {
        let e = entry(&[1, 2, 3, 4, 5, 6, 7, 8, 9, 10, 11, 12]);
        assert!(line(&e).contains("\"payload_b64\":"), "{}", line(&e));
        assert_eq!(serde_json::from_str::<Entry>(&line(&e)).unwrap(), e);
    }

    #[test]
    fn a_json_payload_stays_readable_text() {
        let e = entry(br#"{"total":1234,"delta":3,"gap":false}"#);
        assert!(line(&e).contains(r#""payload":"{\"total\":1234"#));
        assert_eq!(serde_json::from_str::<Entry>(&line(&e)).unwrap(), e);
    }

    #[test]
    fn a_line_with_an_array_of_byte_values_written_by_an_earlier_version_still_reads() {
        let old = r#"{"seq":7,"topic":"t","payload":[0,255,128,10,34],"qos":1,"retain":false}"#;
        let e: Entry = serde_json::from_str(old).unwrap();
        assert_eq!(&e.payload[..], &[0, 255, 128, 10, 34]);
        let text = r#"{"seq":8,"topic":"t","payload":"on","qos":1,"retain":true}"#;
        assert_eq!(
            &serde_json::from_str::<Entry>(text).unwrap().payload[..],
            b"on"
        );
    }

    #[test]
    fn a_line_with_no_payload_or_two_or_bad_base64_is_not_an_entry() {
        for bad in [
            r#"{"seq":1,"topic":"t","qos":1,"retain":false}"#,
            r#"{"seq":1,"topic":"t","payload":"a","payload_b64":"YQ==","qos":1,"retain":false}"#,
            r#"{"seq":1,"topic":"t","payload_b64":"not base64!","qos":1,"retain":false}"#,
        ] {
            assert!(serde_json::from_str::<Entry>(bad).is_err(), "{bad}");
        }
    }
}

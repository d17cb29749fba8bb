//! The Sparkplug B payload: the part of Eclipse Tahu's `sparkplug_b.proto` (EPL-2.0) the gateway
//! writes and reads, as hand-written prost messages with the proto's field numbers, so a build
//! needs no `protoc`. Fields the gateway never uses (metadata, data sets, templates, extensions)
//! are left out: prost skips them when decoding, which is what a host does with fields it does
//! not know.

/// `Payload`: one NBIRTH, NDATA, DBIRTH, DDATA, DDEATH, NCMD or DCMD.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Payload {
    /// Milliseconds since the Unix epoch.
    #[prost(uint64, optional, tag = "1")]
    pub timestamp: Option<u64>,
    #[prost(message, repeated, tag = "2")]
    pub metrics: Vec<Metric>,
    /// 0..255 over the node's messages (none in NDEATH and commands).
    #[prost(uint64, optional, tag = "3")]
    pub seq: Option<u64>,
    #[prost(string, optional, tag = "4")]
    pub uuid: Option<String>,
    #[prost(bytes = "vec", optional, tag = "5")]
    pub body: Option<Vec<u8>>,
}

/// `Payload.Metric`.
#[derive(Clone, PartialEq, prost::Message)]
pub struct Metric {
    #[prost(string, optional, tag = "1")]
    pub name: Option<String>,
    #[prost(uint64, optional, tag = "2")]
    pub alias: Option<u64>,
    #[prost(uint64, optional, tag = "3")]
    pub timestamp: Option<u64>,
    #[prost(uint32, optional, tag = "4")]
    pub datatype: Option<u32>,
    #[prost(bool, optional, tag = "5")]
    pub is_historical: Option<bool>,
    #[prost(bool, optional, tag = "6")]
    pub is_transient: Option<bool>,
    #[prost(bool, optional, tag = "7")]
    pub is_null: Option<bool>,
    #[prost(message, optional, tag = "9")]
    pub properties: Option<PropertySet>,
    #[prost(oneof = "Value", tags = "10, 11, 12, 13, 14, 15, 16")]
    pub value: Option<Value>,
}

/// `Payload.Metric.value`.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum Value {
    /// Int8..Int32 (sign-extended into 32 bits), UInt8..UInt32.
    #[prost(uint32, tag = "10")]
    Int(u32),
    /// Int64 (two's complement), UInt64, DateTime.
    #[prost(uint64, tag = "11")]
    Long(u64),
    #[prost(float, tag = "12")]
    Float(f32),
    #[prost(double, tag = "13")]
    Double(f64),
    #[prost(bool, tag = "14")]
    Boolean(bool),
    #[prost(string, tag = "15")]
    String(String),
    #[prost(bytes = "vec", tag = "16")]
    Bytes(Vec<u8>),
}

/// `Payload.PropertySet`: keys and values side by side.
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertySet {
    #[prost(string, repeated, tag = "1")]
    pub keys: Vec<String>,
    #[prost(message, repeated, tag = "2")]
    pub values: Vec<PropertyValue>,
}

/// `Payload.PropertyValue` (the scalar kinds).
#[derive(Clone, PartialEq, prost::Message)]
pub struct PropertyValue {
    #[prost(uint32, optional, tag = "1")]
    pub r#type: Option<u32>,
    #[prost(bool, optional, tag = "2")]
    pub is_null: Option<bool>,
    #[prost(oneof = "PropertyKind", tags = "3, 4, 5, 6, 7, 8")]
    pub value: Option<PropertyKind>,
}

/// `Payload.PropertyValue.value`.
#[derive(Clone, PartialEq, prost::Oneof)]
pub enum PropertyKind {
    #[prost(uint32, tag = "3")]
    Int(u32),
    #[prost(uint64, tag = "4")]
    Long(u64),
    #[prost(float, tag = "5")]
    Float(f32),
    #[prost(double, tag = "6")]
    Double(f64),
    #[prost(bool, tag = "7")]
    Boolean(bool),
    #[prost(string, tag = "8")]
    String(String),
}

/// Sparkplug `DataType` codes the gateway uses.
pub mod datatype {
    pub const INT64: u32 = 4;
    pub const UINT64: u32 = 8;
    pub const DOUBLE: u32 = 10;
    pub const BOOLEAN: u32 = 11;
    pub const STRING: u32 = 12;
}

impl Metric {
    /// A metric with a name, an alias, a datatype and a value.
    pub fn new(name: &str, alias: Option<u64>, datatype: u32, value: Option<Value>) -> Metric {
        Metric {
            name: Some(name.to_string()),
            alias,
            datatype: Some(datatype),
            is_null: value.is_none().then_some(true),
            value,
            ..Metric::default()
        }
    }

    /// With a string property (`engineering_unit`, say).
    pub fn with_property(mut self, key: &str, value: &str) -> Metric {
        let set = self.properties.get_or_insert_with(PropertySet::default);
        set.keys.push(key.to_string());
        set.values.push(PropertyValue {
            r#type: Some(datatype::STRING),
            is_null: None,
            value: Some(PropertyKind::String(value.to_string())),
        });
        self
    }
}

impl Payload {
    pub fn encode(&self) -> Vec<u8> {
        prost::Message::encode_to_vec(self)
    }

    pub fn decode(bytes: &[u8]) -> Result<Payload, prost::DecodeError> {
        prost::Message::decode(bytes)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_payload_survives_encoding_and_decoding() {
        let p = Payload {
            timestamp: Some(1_700_000_000_000),
            metrics: vec![
                Metric::new(
                    "a0/Total",
                    Some(3),
                    datatype::INT64,
                    Some(Value::Long(-5i64 as u64)),
                )
                .with_property("engineering_unit", "kWh"),
                Metric::new("a0/Rate", Some(4), datatype::DOUBLE, None),
            ],
            seq: Some(255),
            ..Payload::default()
        };
        assert_eq!(Payload::decode(&p.encode()).unwrap(), p);
    }

    #[test]
    fn field_numbers_are_the_tahu_ones() {
        // timestamp = 1 (varint 0x08), seq = 3 (0x18); metric name = 1 (0x0a), alias = 2 (0x10).
        let p = Payload {
            timestamp: Some(1),
            seq: Some(2),
            metrics: vec![Metric {
                name: Some("x".into()),
                alias: Some(7),
                ..Metric::default()
            }],
            ..Payload::default()
        };
        assert_eq!(
            p.encode(),
            [0x08, 1, 0x12, 5, 0x0a, 1, b'x', 0x10, 7, 0x18, 2]
        );
    }

    #[test]
    fn garbage_is_a_decode_error_not_a_panic() {
        assert!(Payload::decode(&[0xff, 0xff, 0xff]).is_err());
    }
}

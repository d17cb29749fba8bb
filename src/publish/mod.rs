//! Readings and availability → MQTT: topic names and payloads (pure) and the MQTT task.

pub mod mqtt;
pub mod payload;
pub mod session;
pub mod spool;
pub mod tls;
pub mod topics;

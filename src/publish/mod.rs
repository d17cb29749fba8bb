//! Readings and availability → MQTT: topic names and payloads (pure) and the MQTT task.

pub mod batch;
pub mod discovery;
pub mod format;
pub mod formats;
pub mod ha_entity;
pub mod homeassistant;
pub mod json;
pub mod meter_entities;
pub mod mqtt;
pub mod payload;
pub mod poller;
pub mod session;
pub mod sparkplug;
pub mod spool;
pub mod spool_place;

#[cfg(test)]
mod discovery_tests;
#[cfg(test)]
mod socket_tests;

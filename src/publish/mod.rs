//! Readings and availability → MQTT. Each output is a task of its own ([`mqtt`]: its
//! connection, outbox, will and hold), fed by [`fanout`] from the buses; its formats are pure
//! encoders ([`format`]) with their MQTT parts ([`lifecycle`]), built per kind by the output
//! registry ([`formats`]); how a message is delivered is decided
//! in [`delivery`]; the gateway's own status and answers are its [`voice`].

pub mod account;
pub mod batch;
pub mod delivery;
pub mod dialer;
pub mod fanout;
pub mod format;
pub mod formats;
pub mod homeassistant;
pub mod json;
pub mod lifecycle;
pub mod mqtt;
pub mod payload;
pub mod poller;
pub mod server;
pub mod session;
pub mod signed;
pub mod sparkplug;
pub mod spool;
pub mod spool_place;
pub mod voice;

pub use server::Server;

#[cfg(test)]
mod oversized_tests;
#[cfg(test)]
mod socket_tests;
#[cfg(test)]
mod toy_output_tests;

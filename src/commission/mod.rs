//! Commissioning: survey a line before a config exists. `cli.rs` says what a command asks;
//! each protocol's commands are in its own folder (`modbus/commission/`: find the units that
//! answer and their models, read one module as the gateway would, clear or preset a channel,
//! change the settings its datasheet documents, read or write raw registers;
//! `mbus/commission/`: find the meters, primary or by the wildcard search, and read one), and
//! `crate::protocols::commission` runs a command by its protocol. What all of them share is
//! here: the line a command names (`target.rs`), who holds a port (`holder.rs`) and why a
//! command stopped (`error.rs`).
//!
//! Everything reuses the gateway's parts: the profiles (identification, settings, channels),
//! the link layer (timeouts, late answers, exclusive port) and the device poller (decoding,
//! clear and preset with read-back). Bad input is refused before anything is written.

pub(crate) mod cli;
pub(crate) mod error;
pub(crate) mod holder;
pub(crate) mod target;

pub use cli::{Commission, LineArgs};
pub use error::CommissionError;
pub use holder::{Holder, holders};

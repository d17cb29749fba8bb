//! Commissioning: survey a line before a config exists, one folder or file per protocol.
//! Modbus (`modbus/`): find the units that answer and their models (`scan`), read one module as
//! the gateway would (`read`), clear or preset a channel, change the settings its datasheet
//! documents (`setup`), and read or write raw registers. M-Bus segments (`mbus.rs`): find the
//! meters (primary addresses, or the wildcard search) and read one meter's answer.
//!
//! Everything here reuses the gateway's parts: the profiles (identification, settings,
//! channels), the link layer (timeouts, late answers, exclusive port) and the device poller
//! (decoding, clear and preset with read-back). Bad input is refused before anything is
//! written.

mod cli;
mod error;
mod holder;
pub mod mbus;
pub(crate) mod modbus;
pub(crate) mod target;

pub use cli::{Commission, run};
pub use error::CommissionError;
pub use holder::{Holder, holders};

pub use modbus::scan::scan_bauds;
pub use modbus::snippet::config_snippet;

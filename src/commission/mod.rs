//! Commissioning: survey a line before a config exists. Find the units that answer and their
//! models (`scan`), read one module as the gateway would (`read`), clear or preset a channel,
//! change the settings its datasheet documents (`setup`), and read or write raw registers.
//!
//! Everything here reuses the gateway's parts: the profiles (identification, settings,
//! channels), the link layer (timeouts, late answers, exclusive port) and the device poller
//! (decoding, clear and preset with read-back). Bad input is refused before anything is
//! written.

mod cli;
mod holder;
pub(crate) mod line;
mod raw;
mod read;
pub(crate) mod scan;
mod setup;
mod snippet;

pub use cli::{Commission, run};
pub use holder::{Holder, holders};

pub use scan::scan_bauds;
pub use snippet::config_snippet;

use crate::driver::modbus::link::LinkError;

/// Why a commissioning command stopped.
#[derive(Debug, thiserror::Error)]
pub enum CommissionError {
    /// The request itself is wrong; nothing was sent to a module.
    #[error("{0}")]
    BadInput(String),
    /// A running gateway (or another program) has the serial port.
    #[error("{port} is in use by {holders}; {advice}")]
    PortHeld {
        port: String,
        holders: String,
        advice: String,
    },
    #[error("unit {unit}: {source}")]
    Link { unit: u8, source: LinkError },
    #[error("unit {unit} refused {what}: {exception:?}")]
    Refused {
        unit: u8,
        what: String,
        exception: tokio_modbus::ExceptionCode,
    },
    #[error("{0}")]
    Failed(String),
}

impl CommissionError {
    /// Exit status: 2 for input refused before anything was sent, 1 otherwise.
    pub fn exit_code(&self) -> u8 {
        match self {
            CommissionError::BadInput(_) => 2,
            _ => 1,
        }
    }
}

//! Why a commissioning command stopped, and the exit status it gives.

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

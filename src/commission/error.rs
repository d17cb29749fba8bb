//! Why a commissioning command stopped, and the exit status it gives, whatever the protocol.

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
    /// The line failed while talking to `unit`.
    #[error("unit {unit}: {source}")]
    Link {
        unit: u8,
        source: Box<dyn std::error::Error + Send + Sync>,
    },
    /// The device answered with an exception: `exception` is its name.
    #[error("unit {unit} refused {what}: {exception}")]
    Refused {
        unit: u8,
        what: String,
        exception: String,
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

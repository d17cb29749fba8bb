//! Why a simulated plant could not be started or changed.

/// The plant could not be started.
#[derive(Debug, thiserror::Error)]
pub enum SimError {
    #[error("simulator config: {0}")]
    Config(String),
    #[error("bus {bus}: {message}")]
    Bus { bus: String, message: String },
}

//! The line a commissioning command talks on: a serial port, or a TCP host. Opening it (each
//! protocol's folder does) first checks that no running gateway holds the port.

use std::path::PathBuf;

use super::error::CommissionError;
use super::holder::holders;
use crate::config::{Parity, Protocol};

/// Where the modules are.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Target {
    Serial { port: PathBuf, parity: Parity },
    Tcp { host: String, port: u16 },
}

impl Target {
    /// From the command line: `--port` or `--host H[:PORT]` (default port 502).
    pub fn parse(
        port: Option<PathBuf>,
        host: Option<String>,
        parity: &str,
    ) -> Result<Target, CommissionError> {
        let parity = match parity {
            "none" => Parity::None,
            "even" => Parity::Even,
            "odd" => Parity::Odd,
            other => {
                return Err(CommissionError::BadInput(format!(
                    "parity {other:?}: use none, even or odd"
                )));
            }
        };
        match (port, host) {
            (Some(port), None) => Ok(Target::Serial { port, parity }),
            (None, Some(h)) => {
                let (host, port) = match h.rsplit_once(':') {
                    Some((h, p)) => (
                        h.to_string(),
                        p.parse::<u16>().ok().filter(|p| *p > 0).ok_or_else(|| {
                            CommissionError::BadInput(format!("--host {h}:{p}: bad TCP port"))
                        })?,
                    ),
                    None => (h, 502),
                };
                Ok(Target::Tcp { host, port })
            }
            _ => Err(CommissionError::BadInput(format!(
                "give --port (a serial device) or --host ({} TCP)",
                Protocol::DEFAULT.title()
            ))),
        }
    }

    pub fn is_serial(&self) -> bool {
        matches!(self, Target::Serial { .. })
    }

    /// Refuses a serial port a running gateway holds, naming the process.
    pub fn check_free(&self) -> Result<(), CommissionError> {
        let Target::Serial { port, .. } = self else {
            return Ok(());
        };
        let gateways: Vec<_> = holders(port)
            .into_iter()
            .filter(|h| h.is_gateway())
            .collect();
        if gateways.is_empty() {
            return Ok(());
        }
        Err(port_held(port, &gateways))
    }
}

pub(crate) fn port_held(port: &std::path::Path, by: &[super::holder::Holder]) -> CommissionError {
    let gateway = by.iter().any(|h| h.is_gateway());
    CommissionError::PortHeld {
        port: port.display().to_string(),
        holders: by
            .iter()
            .map(|h| h.to_string())
            .collect::<Vec<_>>()
            .join(", "),
        advice: if gateway {
            "a running pulsegate gateway polls this line: stop it first (systemctl stop \
             pulsegate), or survey through it over MQTT (<root>/bus/<bus>/scan)"
                .into()
        } else {
            "close that program first".into()
        },
    }
}

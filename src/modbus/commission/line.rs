//! A commissioning [`Target`] as a Modbus line: RTU at a baud rate, or TCP.

use std::time::Duration;

use crate::commission::error::CommissionError;
use crate::commission::holder::holders;
use crate::commission::target::{Target, port_held};
use crate::modbus::config::Line as LinkConfig;
use crate::modbus::driver::link::{Link, LinkError};

impl Target {
    /// The link configuration at `baud` (ignored for TCP).
    pub fn link_config(&self, baud: u32) -> LinkConfig {
        match self {
            Target::Serial { port, parity } => LinkConfig::Rtu {
                port: port.clone(),
                baud,
                parity: *parity,
                stop_bits: 1,
            },
            Target::Tcp { host, port } => LinkConfig::Tcp {
                host: host.clone(),
                port: *port,
            },
        }
    }

    /// A link at `baud`, after checking the port is free.
    pub fn open(&self, baud: u32) -> Result<Link, CommissionError> {
        self.check_free()?;
        Ok(Link::new(self.link_config(baud), Duration::ZERO))
    }

    /// A link error for people: a port that cannot be opened names who has it.
    pub fn error(&self, unit: u8, e: LinkError) -> CommissionError {
        if let (LinkError::Open { .. }, Target::Serial { port, .. }) = (&e, self) {
            let others = holders(port);
            if !others.is_empty() {
                return port_held(port, &others);
            }
        }
        CommissionError::Link {
            unit,
            source: Box::new(e),
        }
    }
}

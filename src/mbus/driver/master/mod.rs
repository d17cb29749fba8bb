//! The M-Bus master: a [`Driver`] over one [`Link`] (a serial level converter or an
//! M-Bus-to-Ethernet converter, `link.rs`), each meter's link state and readout (`device.rs`),
//! its records as the core's channels and samples (`records.rs`, pure), the standard's
//! wildcard search (`search.rs`) and scans asked over MQTT in idle line time (`survey.rs`).
//! It reads; the core counts.

pub mod device;
pub mod link;
pub mod records;
pub mod search;
mod survey;

use std::time::Duration;

use tokio::sync::mpsc::Receiver;

use crate::bus::device::{DeviceRt, PollError};
use crate::bus::driver::{Driver, Executed, Idle, Preempt};
use crate::bus_health::WireCounters;
use crate::command::{CommandError, Request};
use crate::config::Bus;
use crate::sample::Sample;
use crate::scan::ScanRequest;
use crate::state::BusState;
pub use device::{Address, MeterDevice, MeterError};
use link::Link;

/// Wired M-Bus over one line, with the bus's scan requests (carried out in idle time).
pub struct Mbus {
    pub link: Link,
    /// Primary addresses and secondary addresses of the configured meters (a scan names them).
    configured: Vec<Address>,
    requests: Option<Receiver<ScanRequest>>,
    survey: Option<crate::scan::Survey>,
}

/// Runs `task` over an M-Bus master on `bus`'s line until `shutdown`; `None` when the bus's
/// link is not an M-Bus line.
pub fn spawn(
    task: crate::bus::BusTask,
    bus: &Bus,
    scans: Receiver<ScanRequest>,
    shutdown: tokio_util::sync::CancellationToken,
) -> Option<tokio::task::JoinHandle<()>> {
    let line = bus.link.line::<crate::mbus::config::Line>()?;
    let driver = Mbus::for_bus(bus, line).with_scans(Some(scans));
    Some(tokio::spawn(task.run(driver, shutdown)))
}

impl Mbus {
    /// The line of a configured M-Bus bus (its `timeout` where it gives one).
    pub fn for_bus(bus: &Bus, line: &crate::mbus::config::Line) -> Mbus {
        Mbus {
            link: Link::new(line.clone(), bus.timeout),
            configured: bus
                .devices
                .iter()
                .map(|d| MeterDevice::new(d).address)
                .collect(),
            requests: None,
            survey: None,
        }
    }

    /// Takes scan requests from `requests` (see `survey.rs`).
    pub fn with_scans(mut self, requests: Option<Receiver<ScanRequest>>) -> Mbus {
        self.requests = requests;
        self
    }
}

impl Driver for Mbus {
    type Device = MeterDevice;

    fn device(&self, _bus: &Bus, config: &crate::config::Device, _saved: &BusState) -> MeterDevice {
        MeterDevice::new(config)
    }

    async fn poll(
        &mut self,
        device: &mut DeviceRt<MeterDevice>,
        _preempt: Preempt<'_>,
    ) -> Result<Vec<Sample>, PollError<MeterError>> {
        device.poll_meter(&mut self.link).await
    }

    /// A meter's registers cannot be written: only `set_reading` (the core's) applies.
    async fn execute(
        &mut self,
        device: &mut DeviceRt<MeterDevice>,
        _request: &Request,
    ) -> Executed {
        Executed {
            failed: Some(CommandError::NotWritable {
                device: device.name.to_string(),
                why: "an M-Bus meter's registers are the meter's own; use set_reading to match \
                      its reading",
            }),
            ..Executed::default()
        }
    }

    fn wire(&self) -> (WireCounters, Duration) {
        (self.link.counters, self.link.busy)
    }

    fn is_line_fault(&self, e: &PollError<MeterError>) -> bool {
        matches!(e, PollError::Protocol(m) if m.is_line_fault())
    }

    fn ready_for_commands(&self, _device: &DeviceRt<MeterDevice>) -> bool {
        true
    }

    async fn idle(&mut self, idle: Idle<'_>) -> bool {
        let scanning = survey::Scanning {
            link: &mut self.link,
            survey: &mut self.survey,
            requests: &mut self.requests,
            configured: &self.configured,
        };
        survey::idle_step(scanning, idle).await
    }

    fn close(&mut self) {
        self.link.close();
    }
}

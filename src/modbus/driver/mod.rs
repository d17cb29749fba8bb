//! The Modbus RTU/TCP driver: a [`Driver`] over one [`Link`] (transport: `link.rs`, the RTU
//! port `serial.rs`, timers `timer.rs`), the per-device state and planned reads (`device.rs`),
//! identification (`identity.rs`), clear/preset (`execute.rs`), counter run state of modules
//! with a command register (`run_state.rs`), idle-time scans (`survey.rs`), and the pure rules
//! of a noisy line (`sizing.rs`, `retry.rs`). Only this folder knows Modbus.

mod device;
mod discover;
mod execute;
pub mod identity;
pub mod link;
pub mod probe;
mod retry;
mod run_control;
mod run_state;
mod serial;
pub mod sizing;
pub mod survey;
mod timer;

/// The log filter that keeps tokio-modbus's own logs to its errors (a late or garbled answer
/// is the driver's to count and say, not the library's to log at each frame).
pub const QUIET_LIBRARY: &str = "tokio_modbus=error";

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc::Receiver;

use crate::bus::device::{DeviceRt, PollError};
use crate::bus::driver::{Driver, Executed, Idle, Preempt};
use crate::bus_health::WireCounters;
use crate::command::Request;
use crate::config::Bus;
use crate::modbus::config::plan::Wire;
use crate::sample::Sample;
use crate::scan::ScanRequest;
use crate::scan::Survey;
use crate::state::BusState;
pub use device::{ModbusDevice, ModbusError};
use identity::Identity;
use link::Link;

/// Modbus RTU or TCP over one [`Link`], with the bus's scan requests (asked in idle time).
pub struct Modbus {
    pub link: Link,
    /// Identification of every model configured on the bus, to name what a wrong module is.
    known: Arc<[Identity]>,
    /// Configured units (a scan skips them).
    units: Vec<u8>,
    scan: Option<Survey>,
    requests: Option<Receiver<ScanRequest>>,
}

/// Runs `task` over a Modbus driver on `bus`'s line until `shutdown`; `None` when the bus's
/// link is not a Modbus line.
pub fn spawn(
    task: crate::bus::BusTask,
    bus: &Bus,
    scans: Receiver<ScanRequest>,
    shutdown: tokio_util::sync::CancellationToken,
) -> Option<tokio::task::JoinHandle<()>> {
    let line = bus.link.line::<crate::modbus::config::Line>()?;
    let driver = Modbus::for_bus(bus, line).with_scans(Some(scans));
    Some(tokio::spawn(task.run(driver, shutdown)))
}

impl Modbus {
    /// The link of a configured bus on `line` (devices with a baud rate of their own get it).
    pub fn for_bus(bus: &Bus, line: &crate::modbus::config::Line) -> Modbus {
        let mut link = Link::new(line.clone(), bus.guard);
        for d in &bus.devices {
            if let Some(baud) = d.baud {
                link.set_unit_baud(d.unit, baud);
            }
        }
        let configured: Vec<_> = bus.devices.iter().map(|d| d.profile.clone()).collect();
        Modbus {
            link,
            known: identity::known(&configured),
            units: bus.devices.iter().map(|d| d.unit).collect(),
            scan: None,
            requests: None,
        }
    }

    /// Takes scan requests from `requests` (see [`survey`]).
    pub fn with_scans(mut self, requests: Option<Receiver<ScanRequest>>) -> Modbus {
        self.requests = requests;
        self
    }

    /// How the planner prices a read on this bus (until a device's turnaround is measured).
    pub fn wire_pricing(&self) -> Wire {
        Wire::for_line(self.link.timing().as_ref())
    }
}

impl Driver for Modbus {
    type Device = ModbusDevice;

    fn device(&self, bus: &Bus, config: &crate::config::Device, saved: &BusState) -> ModbusDevice {
        let key = crate::state::device_key(config.unit, &config.model);
        ModbusDevice::new(bus, config, self.wire_pricing(), saved.holes_of(&key))
            .with_known(self.known.clone())
    }

    async fn poll(
        &mut self,
        device: &mut DeviceRt<ModbusDevice>,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Sample>, PollError<ModbusError>> {
        device.poll(&mut self.link, preempt).await
    }

    async fn execute(
        &mut self,
        device: &mut DeviceRt<ModbusDevice>,
        request: &Request,
    ) -> Executed {
        device.execute(&mut self.link, request).await
    }

    fn wire(&self) -> (WireCounters, Duration) {
        (self.link.counters, self.link.busy)
    }

    fn is_line_fault(&self, e: &PollError<ModbusError>) -> bool {
        matches!(e, PollError::Protocol(ModbusError::Link(l)) if l.is_line_fault())
    }

    fn ready_for_commands(&self, device: &DeviceRt<ModbusDevice>) -> bool {
        device.proto.discovered()
    }

    async fn idle(&mut self, idle: Idle<'_>) -> bool {
        survey::idle_step(
            &mut self.scan,
            &mut self.requests,
            &mut self.link,
            idle.until,
            &self.units,
            idle.bus,
            idle.out,
            idle.shutdown,
        )
        .await
    }

    fn close(&mut self) {
        self.link.close();
    }
}

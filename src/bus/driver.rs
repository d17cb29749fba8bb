//! The protocol seam: what the bus task asks of a protocol. The bus task keeps the schedule,
//! availability, command priority, stats and state flushing; a driver discovers a device, polls
//! it and carries out clear/preset on it, and reports what the wire did. Modbus RTU/TCP
//! ([`Modbus`]) is the one driver today; a new protocol is a new implementation of [`Driver`].

use std::sync::Arc;
use std::time::Duration;

use tokio::sync::mpsc::{Receiver, UnboundedSender};
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::device::{DeviceRt, PollError, ProtocolError};
use super::identity::Identity;
use super::link::Link;
use super::modbus::{ModbusDevice, ModbusError};
use super::stats::WireCounters;
use super::survey::{ScanRequest, Survey};
use crate::command::Request;
use crate::config::Bus;
use crate::plan::Wire;
use crate::reading::{Output, Reading};
use crate::state::BusState;

/// The outcome of a command: readings to publish (booked counts and the event readings) and the
/// result (the count read back for a single channel).
pub struct Executed {
    pub readings: Vec<Reading>,
    pub result: Result<Option<i64>, crate::command::CommandError>,
}

/// A poll failure of driver `D`: its protocol's own, or one the core understands.
pub type Failure<D> = PollError<<<D as Driver>::Device as DeviceState>::Error>;

/// Asked between transactions: `true` when a command waits and the poll should give way.
pub type Preempt<'a> = &'a (dyn Fn() -> bool + Sync);

/// One protocol on one bus.
#[allow(async_fn_in_trait)] // used by the bus task only, never as a trait object across threads
pub trait Driver {
    /// What the protocol keeps of one device (Modbus: [`ModbusDevice`]); the bus core holds it
    /// in the device's [`DeviceRt::proto`] and never looks inside.
    type Device: DeviceState;
    /// The protocol's state for a configured device, from the bus's saved state.
    fn device(&self, bus: &Bus, config: &crate::config::Device, saved: &BusState) -> Self::Device;
    /// Learns what the device is when due (identity, work modes, the registers a poll needs).
    async fn discover(
        &mut self,
        device: &mut DeviceRt<Self::Device>,
        preempt: Preempt<'_>,
    ) -> Result<(), PollError<<Self::Device as DeviceState>::Error>>;
    /// One poll of a device (discovering it first when due): its readings.
    async fn poll(
        &mut self,
        device: &mut DeviceRt<Self::Device>,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Reading>, PollError<<Self::Device as DeviceState>::Error>>;
    /// Carries out a clear or preset (the device is discovered and online).
    async fn execute(&mut self, device: &mut DeviceRt<Self::Device>, request: &Request)
    -> Executed;
    /// What the wire did so far: transactions, timeouts, errors, and the time it was busy.
    fn wire(&self) -> (WireCounters, Duration);
    /// A fault of the line itself (port gone, connection refused), as opposed to one device.
    fn is_line_fault(&self, e: &PollError<<Self::Device as DeviceState>::Error>) -> bool;
    /// Whether the device can take a command now (Modbus: its work modes are known).
    fn ready_for_commands(&self, device: &DeviceRt<Self::Device>) -> bool;
    /// Idle line time before the next poll: a driver may use it (Modbus: scans of unconfigured
    /// units). `true` when it did something (the bus then looks at its schedule again).
    async fn idle(&mut self, _idle: Idle<'_>) -> bool {
        false
    }
    /// Closes the port or connection at shutdown.
    fn close(&mut self);
}

/// What the bus core may tell or ask a driver's per-device state. Every method has a default
/// that does nothing: a protocol without such state needs none of them.
pub trait DeviceState {
    /// The protocol's own poll failures.
    type Error: ProtocolError;
    /// A poll failed with `e` (a new error: the same one again is not told twice).
    fn poll_failed(&mut self, _e: &PollError<Self::Error>) {}
    /// The device went offline: whatever answers next may be another device.
    fn went_offline(&mut self) {}
    /// The device's measured turnaround, in seconds, for the bus stats.
    fn turnaround(&self) -> Option<f64> {
        None
    }
    /// How the device's poll is cut into requests now, for the bus stats (Modbus: reads
    /// shortened on a noisy line).
    fn request_size(&self) -> Option<super::stats::RequestSize> {
        None
    }
    /// Adds what the protocol keeps across restarts to the bus's state (Modbus: the holes).
    fn save(&self, _state: &mut BusState) {}
    /// The key of that state in the state file, so saved state no device claims is kept.
    fn state_key(&self) -> Option<String> {
        None
    }
}

/// What the bus hands a driver for its idle time.
pub struct Idle<'a> {
    /// The next poll: the idle time ends here.
    pub until: Instant,
    pub bus: &'a str,
    pub out: &'a UnboundedSender<Output>,
    pub shutdown: &'a CancellationToken,
}

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

impl Modbus {
    /// The link of a configured bus (devices with a baud rate of their own get it).
    pub fn for_bus(bus: &Bus) -> Modbus {
        let mut link = Link::new(bus.link.clone(), bus.guard);
        for d in &bus.devices {
            if let Some(baud) = d.baud {
                link.set_unit_baud(d.unit, baud);
            }
        }
        let configured: Vec<_> = bus.devices.iter().map(|d| d.profile.clone()).collect();
        Modbus {
            link,
            known: super::identity::known(&configured),
            units: bus.devices.iter().map(|d| d.unit).collect(),
            scan: None,
            requests: None,
        }
    }

    /// Takes scan requests from `requests` (see [`super::survey`]).
    pub fn with_scans(mut self, requests: Option<Receiver<ScanRequest>>) -> Modbus {
        self.requests = requests;
        self
    }

    /// How the planner prices a read on this bus (until a device's turnaround is measured).
    pub fn wire_pricing(&self) -> Wire {
        match self.link.timing() {
            Some(t) => Wire::rtu(&t, crate::plan::DEFAULT_TURNAROUND),
            None => Wire::tcp(),
        }
    }
}

impl Driver for Modbus {
    type Device = ModbusDevice;

    fn device(&self, bus: &Bus, config: &crate::config::Device, saved: &BusState) -> ModbusDevice {
        let key = crate::state::device_key(config.unit, &config.model);
        ModbusDevice::new(bus, config, self.wire_pricing(), saved.holes_of(&key))
            .with_known(self.known.clone())
    }

    async fn discover(
        &mut self,
        device: &mut DeviceRt<ModbusDevice>,
        preempt: Preempt<'_>,
    ) -> Result<(), PollError<ModbusError>> {
        device.discover(&mut self.link, preempt).await
    }

    async fn poll(
        &mut self,
        device: &mut DeviceRt<ModbusDevice>,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Reading>, PollError<ModbusError>> {
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
        super::survey::idle_step(
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

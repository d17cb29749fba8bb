//! The protocol seam: what the bus task asks of a protocol. The bus task keeps the schedule,
//! availability, command priority, stats and state flushing; a driver polls a device
//! (discovering it first when due), carries out clear/preset on it, and reports what the wire
//! did. Modbus RTU/TCP (`crate::driver::modbus`) is the one driver today; a new protocol is a
//! folder under `src/driver/` with an implementation of [`Driver`].

use std::time::Duration;

use tokio::sync::mpsc::UnboundedSender;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::device::{DeviceRt, PollError, ProtocolError};
use crate::bus_health::WireCounters;
use crate::command::Request;
use crate::config::Bus;
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
    /// What the protocol keeps of one device (Modbus: `ModbusDevice`); the bus core holds it
    /// in the device's [`DeviceRt::proto`] and never looks inside.
    type Device: DeviceState;
    /// The protocol's state for a configured device, from the bus's saved state.
    fn device(&self, bus: &Bus, config: &crate::config::Device, saved: &BusState) -> Self::Device;
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
    /// A problem the protocol found in a good poll (Modbus: a quadrature pair's mode words
    /// disagree), when it changed since the last call: `Some(Some(status))` is published as the
    /// device's status while it lasts, `Some(None)` (online again) when it is over.
    fn status_change(&mut self) -> Option<Option<&'static str>> {
        None
    }
    /// The device went offline: whatever answers next may be another device.
    fn went_offline(&mut self) {}
    /// The device's measured turnaround, in seconds, for the bus stats.
    fn turnaround(&self) -> Option<f64> {
        None
    }
    /// How the device's poll is cut into requests now, for the bus stats (Modbus: reads
    /// shortened on a noisy line).
    fn request_size(&self) -> Option<crate::bus_health::RequestSize> {
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

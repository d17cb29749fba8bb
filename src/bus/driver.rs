//! The protocol seam: what the bus task asks of a protocol. The bus task keeps the schedule,
//! availability, command priority, stats and state flushing, and it counts: the counters,
//! readings, plausibility, events, publish policy, metering and metrics are the core's, the same
//! for every protocol. A driver polls a device (discovering it first when due, and declaring its
//! channels to the core), carries out clear/preset on it, and returns what it read in raw terms
//! ([`crate::sample`]); it never counts. Modbus RTU/TCP (`crate::modbus::driver`) and M-Bus
//! (`crate::mbus::driver::master`) are the drivers today; a new protocol is a folder
//! `src/<protocol>/` whose `driver/` implements [`Driver`], spawned by `crate::protocols`.

use std::time::Duration;

use tokio::sync::mpsc::UnboundedSender;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::device::{DeviceRt, PollError, ProtocolError};
use crate::bus_health::WireCounters;
use crate::command::{CommandError, Request};
use crate::config::Bus;
use crate::event::Event;
use crate::reading::Output;
use crate::sample::Sample;
use crate::state::BusState;

/// What a driver did for a clear or preset, in raw terms; the core books it
/// ([`DeviceRt::book_command`]): the counts read before the write like a poll's, then each
/// channel written rebased on its read-back (`cleared`, `preset`), and the command's result.
#[derive(Debug, Default)]
pub struct Executed {
    /// Counts read before the write, so nothing counted up to it is lost.
    pub before: Vec<Sample>,
    /// One entry per channel the command acts on (empty when it failed).
    pub written: Vec<Written>,
    /// Why the command failed, if it did (what was read before is booked all the same).
    pub failed: Option<CommandError>,
}

/// One channel a clear or preset wrote.
#[derive(Debug, Clone)]
pub struct Written {
    /// The channel's place in the list its device's discovery declared.
    pub channel: usize,
    pub wrote: Wrote,
    /// The count read back after the write (`None`: not read back).
    pub read_back: Option<Sample>,
    /// From the write to the read-back: pulses the input may count meanwhile.
    pub elapsed_ms: u64,
}

/// What a command wrote to a channel's count.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum Wrote {
    Cleared,
    Preset(i64),
}

impl Wrote {
    /// The count the channel should read right after the write.
    pub fn value(self) -> i64 {
        match self {
            Wrote::Cleared => 0,
            Wrote::Preset(v) => v,
        }
    }

    /// The event its reading carries.
    pub fn event(self) -> Event {
        match self {
            Wrote::Cleared => Event::Cleared,
            Wrote::Preset(_) => Event::Preset,
        }
    }
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
    /// One poll of a device: what it read, one sample per channel that answered. Discovery
    /// first when due: the channels it finds, and how each counts, are declared to the core
    /// with [`DeviceRt::declare`] (which creates or resumes their counters); a sample names its
    /// channel by its place in that list.
    async fn poll(
        &mut self,
        device: &mut DeviceRt<Self::Device>,
        preempt: Preempt<'_>,
    ) -> Result<Vec<Sample>, PollError<<Self::Device as DeviceState>::Error>>;
    /// Carries out a clear or preset (the device is discovered and online): what it read
    /// before, wrote and read back.
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
    /// The core found a count reset the gateway did not make (a module restart, a clear by
    /// someone else, a meter replaced): what the protocol learnt of the device may be stale.
    fn reset_found(&mut self) {}
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
    fn saved_key(&self) -> Option<String> {
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

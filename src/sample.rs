//! What a driver hands the bus core: the channels a device has and how each counts (at
//! discovery), and per poll what the wire said about each and when it arrived. Raw: a count as
//! the device holds it, with the width and direction it wraps in; a meter register with the
//! value it rolls over at; a gauge value. The core (`bus/book.rs`) turns them into deltas,
//! totals and events with the channel's [`Counter`], once, for every protocol. Pure.
//!
//! [`Counter`]: crate::counter::Counter

use std::sync::Arc;
use std::time::SystemTime;

use crate::config::units::ChannelUnits;
pub use crate::counter::Direction;
use crate::counter::{CounterSpec, Restart, Stamp};
use crate::profile::ChannelKind;
pub use crate::reading::Measure;

/// When an answer arrived: the wall clock for `ts`, both clocks for the counter.
#[derive(Debug, Clone, Copy, PartialEq)]
pub struct At {
    pub wall: SystemTime,
    pub stamp: Stamp,
}

impl At {
    /// Now, on both clocks.
    pub fn now() -> At {
        let (wall, mono) = crate::reading::now();
        At {
            wall,
            stamp: crate::reading::stamp(wall, mono),
        }
    }
}

/// The range a count wraps in: `2^bits` values (Modbus: 16 or 32-bit registers), moving in
/// `direction` (encoders both ways, unsigned inputs up, a counter commanded to count down down).
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Wrap {
    pub bits: u32,
    pub direction: Direction,
}

impl Wrap {
    /// Number of distinct count values.
    pub fn modulus(self) -> i64 {
        1i64 << self.bits
    }
}

/// How a channel counts, as its driver's discovery found it.
#[derive(Debug, Clone, Copy, PartialEq)]
pub enum Counting {
    /// A pulse count the device keeps: it wraps as `wrap` says, and a device that restarts or is
    /// cleared by someone else starts it again from zero. `max_rate_hz`: the highest input rate
    /// it can count (pulses per second), which bounds what a jump may mean.
    Count { wrap: Wrap, max_rate_hz: f64 },
    /// An absolute meter register: counts up and rolls over to 0 at `rollover` (an 8-digit BCD
    /// register at 10^8, a 32-bit integer at 2^32). One that goes down by more than a roll-over
    /// explains is a meter replaced (a `reset`, counted on from its new value, never a negative
    /// delta). `max_rate_hz`: the most register steps per second the meter can make (finite:
    /// it tells a roll-over from a replacement).
    Register { rollover: i64, max_rate_hz: f64 },
    /// A measured value (a temperature, a flow): nothing to count.
    Gauge,
}

impl Counting {
    /// The counter's rules for this channel; `None` for a gauge.
    pub(crate) fn spec(self) -> Option<CounterSpec> {
        match self {
            Counting::Count { wrap, max_rate_hz } => Some(CounterSpec {
                modulus: wrap.modulus(),
                direction: wrap.direction,
                max_rate_hz,
                restart: Restart::FromZero,
            }),
            Counting::Register {
                rollover,
                max_rate_hz,
            } => Some(CounterSpec {
                modulus: rollover,
                direction: Direction::Up,
                max_rate_hz,
                restart: Restart::FromFirstRead,
            }),
            Counting::Gauge => None,
        }
    }
}

/// One channel of a device, as its driver's discovery declares it to the bus core (which then
/// creates its counter, or resumes it from the saved state). Channels the config disables are
/// not declared; a sample names its channel by its place in the declared list.
#[derive(Debug, Clone, PartialEq)]
pub struct Channel {
    pub name: Arc<str>,
    /// What the channel counts in the device's current work mode (a ZH-YX1600 `di1` is an
    /// input counter in one mode and an encoder in another); a meter register is a counter.
    pub kind: ChannelKind,
    pub counting: Counting,
    /// What one step of a count is worth and its unit, where the device says so (an M-Bus
    /// register in 10^-3 m³ steps: scale 0.001, unit m³); a gauge's unit (no scale). A
    /// `scale` in the channel's config wins. `None`: raw pulses.
    pub units: Option<ChannelUnits>,
}

/// What the wire said about a channel.
#[derive(Debug, Clone, PartialEq)]
pub enum Value {
    /// A pulse count as the device holds it (signed for encoders), and the range it wraps in
    /// now (a ZH-YX1600 counter's direction follows its command word).
    Count { count: i64, wrap: Wrap },
    /// An absolute meter register and the value it rolls over at.
    Register { value: i64, rollover: i64 },
    /// A measured value.
    Gauge(Measure),
}

impl Value {
    /// The count or register value; `None` for a gauge.
    pub fn count(&self) -> Option<i64> {
        match self {
            Value::Count { count, .. } => Some(*count),
            Value::Register { value, .. } => Some(*value),
            Value::Gauge(_) => None,
        }
    }

    /// Counts `spec` under this value's wrap (a changed run direction, a register's roll-over).
    pub(crate) fn shape(&self, spec: &mut CounterSpec) {
        match self {
            Value::Count { wrap, .. } => {
                spec.modulus = wrap.modulus();
                spec.direction = wrap.direction;
            }
            Value::Register { rollover, .. } => {
                spec.modulus = *rollover;
                spec.direction = Direction::Up;
            }
            Value::Gauge(_) => {}
        }
    }
}

/// One channel's raw reading from one poll.
#[derive(Debug, Clone, PartialEq)]
pub struct Sample {
    /// The channel's place in the list its device's discovery declared.
    pub channel: usize,
    /// When the answer arrived.
    pub at: At,
    pub value: Value,
    /// Frequency and speed, where the device measures them.
    pub freq_hz: Option<f64>,
    pub rpm: Option<f64>,
    /// The count starts over here and nothing before it is a delta: the driver started a
    /// stopped counter (Modbus: ZH-YX1600 after power-up), or found another meter in the
    /// place of the last. Booked as a `reset` with no delta.
    pub starts_over: bool,
}

impl Sample {
    /// A count of `channel` that arrived `at`, wrapping as `wrap` says.
    pub fn count(channel: usize, at: At, count: i64, wrap: Wrap) -> Sample {
        Sample::of(channel, at, Value::Count { count, wrap })
    }

    /// A meter register of `channel` that arrived `at`, rolling over at `rollover`.
    pub fn register(channel: usize, at: At, value: i64, rollover: i64) -> Sample {
        Sample::of(channel, at, Value::Register { value, rollover })
    }

    /// A gauge value of `channel` that arrived `at`.
    pub fn gauge(channel: usize, at: At, value: Measure) -> Sample {
        Sample::of(channel, at, Value::Gauge(value))
    }

    fn of(channel: usize, at: At, value: Value) -> Sample {
        Sample {
            channel,
            at,
            value,
            freq_hz: None,
            rpm: None,
            starts_over: false,
        }
    }

    /// With the frequency and speed measured beside the count.
    pub fn with_rates(mut self, freq_hz: Option<f64>, rpm: Option<f64>) -> Sample {
        self.freq_hz = freq_hz;
        self.rpm = rpm;
        self
    }

    /// The count starts over here (see [`Sample::starts_over`]).
    pub fn starting_over(mut self) -> Sample {
        self.starts_over = true;
        self
    }
}

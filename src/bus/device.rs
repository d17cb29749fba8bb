//! One device on a bus as the protocol-neutral bus core keeps it: channels and counters,
//! availability, latencies, status; the protocol's own state rides along in `proto`. What a
//! driver read is booked into the counters in `book.rs`.

use std::collections::BTreeMap;
use std::sync::Arc;

use tokio::time::Instant;

use crate::config::units::ChannelUnits;
use crate::config::{Bus, Device};
use crate::counter::{Counter, CounterState, Update};
use crate::metrics::DeviceMetrics;
use crate::profile::{ChannelKind, Profile};
use crate::reading::{Measure, Reading};
use crate::sample::Sample;
use crate::state::{channel_key, is_channel_of};

/// Why a poll produced no readings: the protocol's own failure `E` (Modbus:
/// [`ModbusError`](super::modbus::ModbusError)), or one the core understands.
#[derive(Debug, thiserror::Error)]
pub enum PollError<E> {
    /// The protocol's own failure (no answer, a refusal, a broken line).
    #[error("{0}")]
    Protocol(E),
    #[error("{0}")]
    Profile(String),
    /// A command is waiting: the poll stepped aside after the transaction in flight.
    #[error("poll interrupted by a command")]
    Preempted,
}

/// A protocol's own poll failure, as the bus core sees it.
pub trait ProtocolError: std::fmt::Display + std::fmt::Debug {
    /// The device said something (a refusal, a garbled answer): it is there.
    fn device_answered(&self) -> bool;
    /// Why the device that answered is not the one configured (Modbus: another model), if so:
    /// it is taken out of service (status `wrong_model`) and polled again after a backoff.
    fn out_of_service(&self) -> Option<&str> {
        None
    }
}

impl<E: ProtocolError> PollError<E> {
    /// The device said something: it is there, even if it refused.
    pub fn device_answered(&self) -> bool {
        match self {
            PollError::Protocol(e) => e.device_answered(),
            _ => true,
        }
    }

    /// Why the device is not the one configured, if that is the failure.
    pub fn out_of_service(&self) -> Option<&str> {
        match self {
            PollError::Protocol(e) => e.out_of_service(),
            _ => None,
        }
    }

    /// Not a failure of the device at all.
    pub fn is_preempted(&self) -> bool {
        matches!(self, PollError::Preempted)
    }
}

/// A channel being polled, as its driver declared it (`sample::Channel`), with its counter.
pub(crate) struct ChannelRt {
    pub(crate) name: Arc<str>,
    pub(crate) kind: ChannelKind,
    /// `None` for a gauge: nothing to count.
    pub(crate) counter: Option<Counter>,
    /// What the driver declared of its units (a meter register's step and unit, a gauge's
    /// unit); a `scale` in the config wins.
    pub(crate) units: Option<Arc<ChannelUnits>>,
}

impl ChannelRt {
    /// This channel's reading of `count`, booked as `update`, from `sample`.
    pub(crate) fn reading(
        &self,
        device: &Arc<str>,
        sample: &Sample,
        count: i64,
        update: Update,
    ) -> Reading {
        Reading {
            device: device.clone(),
            channel: self.name.clone(),
            ts: sample.at.wall,
            count,
            freq_hz: sample.freq_hz,
            rpm: sample.rpm,
            update,
            kind: self.kind,
            units: None,
            after_seq: None,
            meter: None,
            measured: None,
        }
    }

    /// This channel's reading of a gauge's value, from `sample`.
    pub(crate) fn measured(&self, device: &Arc<str>, sample: &Sample, value: Measure) -> Reading {
        let update = Update {
            delta: 0,
            total: 0,
            seq: 0,
            rate_hz: None,
            event: None,
        };
        Reading {
            measured: Some(value),
            ..self.reading(device, sample, 0, update)
        }
    }
}

/// The state of one device on its bus, as the bus core keeps it: channels and their counters,
/// availability, latencies, status. What a protocol keeps of the device (Modbus: unit, register
/// plan, holes, identity) is `proto`, the driver's [`Driver::Device`]; the core never looks
/// inside it.
///
/// [`Driver::Device`]: super::driver::Driver::Device
pub struct DeviceRt<P> {
    pub name: Arc<str>,
    pub config: Device,
    pub(crate) profile: Arc<Profile>,
    /// The channels the driver declared, with their counters: the core's alone (a driver
    /// hands samples in and never counts).
    pub(super) channels: Vec<ChannelRt>,
    /// Saved counter states of channels not declared (yet, or any more).
    pub(super) saved: BTreeMap<String, CounterState>,
    /// Online, offline, not yet seen; failures and backoff (a state machine of its own).
    pub availability: super::availability::Availability,
    /// Poll latencies (seconds), most recent last, for p50/p99.
    pub latencies: std::collections::VecDeque<f64>,
    /// Time between good polls (seconds, moving average), against the configured interval.
    pub achieved_interval: Option<f64>,
    last_good_poll: Option<Instant>,
    /// Why the device is out of service: it is not the configured one (Modbus: a wrong model).
    pub out_of_service: Option<String>,
    /// This device's Prometheus handles.
    pub metrics: DeviceMetrics,
    /// What the protocol keeps of this device.
    pub proto: P,
}

impl<P> DeviceRt<P> {
    /// A reading of `channel` was not published: its sequence number goes back, so `seq`
    /// counts published readings only.
    pub(crate) fn withdraw_seq(&mut self, channel: &str) {
        let channel = self.channels.iter_mut().find(|c| &*c.name == channel);
        if let Some(c) = channel.and_then(|c| c.counter.as_mut()) {
            c.state.seq = c.state.seq.saturating_sub(1);
        }
    }

    /// A device of `config` on `bus`, with the counter states `saved` of its channels and
    /// what its protocol keeps of it.
    pub fn new(
        bus: &Bus,
        config: &Device,
        saved: &BTreeMap<String, CounterState>,
        proto: P,
    ) -> DeviceRt<P> {
        DeviceRt {
            name: Arc::from(config.name.as_str()),
            profile: config.profile.clone(),
            channels: Vec::new(),
            saved: saved
                .iter()
                .filter(|(k, _)| is_channel_of(k, config.place(), &config.model))
                .map(|(k, v)| (k.clone(), v.clone()))
                .collect(),
            availability: super::availability::Availability::new(
                bus.offline_after,
                bus.backoff_min,
                bus.backoff_max,
            ),
            latencies: std::collections::VecDeque::new(),
            achieved_interval: None,
            last_good_poll: None,
            out_of_service: None,
            metrics: DeviceMetrics::disabled(),
            config: config.clone(),
            proto,
        }
    }

    /// Records into the gateway's metrics (without: nothing is recorded).
    pub fn with_metrics(mut self, metrics: DeviceMetrics) -> DeviceRt<P> {
        self.metrics = metrics;
        self
    }

    /// A good answer after `d`: its latency in the metrics (and so the page's last answer)
    /// and in the window of the p50/p99.
    pub fn answered_in(&mut self, d: std::time::Duration) {
        self.metrics.latency(d);
        if self.latencies.len() >= 256 {
            self.latencies.pop_front();
        }
        self.latencies.push_back(d.as_secs_f64());
    }

    /// The state file's key of `channel` (the file's format: unit, model, channel).
    pub(crate) fn channel_key(&self, channel: &str) -> String {
        channel_key(self.config.place(), &self.config.model, channel)
    }

    /// Counter state of every channel, keyed for the state file (channels not discovered yet
    /// keep what was loaded).
    pub fn counter_states(&self) -> BTreeMap<String, CounterState> {
        let mut out = self.saved.clone();
        for ch in &self.channels {
            if let Some(c) = &ch.counter {
                out.insert(self.channel_key(&ch.name), c.state.clone());
            }
        }
        out
    }

    /// `Some(true)` online, `Some(false)` offline, `None` not yet seen.
    pub fn online(&self) -> Option<bool> {
        self.availability.online()
    }

    /// The device was away: every channel's next delta covers the gap.
    pub fn mark_gap(&mut self) {
        for c in self.channels.iter_mut().filter_map(|c| c.counter.as_mut()) {
            c.mark_gap();
        }
    }

    /// A good poll: the achieved poll interval (moving average), for the bus stats.
    pub(crate) fn note_good_poll(&mut self) {
        let now = Instant::now();
        if let Some(last) = self.last_good_poll.replace(now) {
            let gap = (now - last).as_secs_f64();
            self.achieved_interval =
                Some(self.achieved_interval.map_or(gap, |a| a * 0.8 + gap * 0.2));
        }
    }
}

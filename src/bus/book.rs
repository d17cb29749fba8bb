//! What a driver read, booked into the device's counters, the same for every protocol: the
//! channels its discovery declares (counters kept, resumed from the saved state, or new), the
//! samples of a poll, and what a clear or preset wrote and read back. Readings out. Pure: no
//! I/O, no runtime.

use std::collections::BTreeMap;
use std::sync::Arc;

use super::device::{ChannelRt, DeviceRt};
use super::driver::{DeviceState, Executed, Written};
use crate::command::CommandError;
use crate::config::units::ChannelUnits;
use crate::counter::Counter;
use crate::event::Event;
use crate::metering::meter::MeterOffset;
use crate::reading::Reading;
use crate::sample::{Channel, Sample, Value};

/// A meter register read for the first time, with its step and unit known and no meter
/// reading set: the channel's meter reading starts at what the meter shows (its total starts
/// at 0 like every count's), so `reading` is the meter's own register from the first poll and
/// moves with the total from there (a replaced meter's reading goes on from the old one's,
/// until `set_reading` says otherwise).
fn first_meter_reading(
    counter: &mut Counter,
    units: Option<&ChannelUnits>,
    count: i64,
    at_ms: u64,
) {
    let Some(scale) = units.and_then(|u| u.scale) else {
        return;
    };
    if counter.state.meter.is_some() {
        return;
    }
    let shown = scale.times(count);
    counter.state.meter = MeterOffset::to_show(&shown, &scale, counter.state.total, at_ms as i64);
}

impl<P> DeviceRt<P> {
    /// The channels the device has now, in the order its samples name them, as the driver's
    /// discovery found them. A channel keeps its counter across a rebuild (counted under its
    /// new rules); a new one resumes its saved state (the first delta covers the time away) or
    /// starts afresh; one the device no longer has keeps its state for when it comes back.
    pub fn declare(&mut self, channels: Vec<Channel>) {
        let mut old: BTreeMap<Arc<str>, Counter> = self
            .channels
            .drain(..)
            .filter_map(|c| Some((c.name, c.counter?)))
            .collect();
        for ch in channels {
            let kept = old.remove(&ch.name);
            let saved = self.saved.remove(&self.channel_key(&ch.name));
            let counter = ch.counting.spec().map(|spec| match (kept, saved) {
                (Some(c), _) => c.with_spec(spec),
                (None, Some(saved)) => Counter::resume(spec, saved),
                (None, None) => Counter::new(spec),
            });
            self.channels.push(ChannelRt {
                name: ch.name,
                kind: ch.kind,
                counter,
                units: ch.units.map(Arc::new),
            });
        }
        for (name, gone) in old {
            tracing::info!(device = %self.name, channel = %name, total = gone.state.total, "channel no longer declared (a work mode changed); its state is kept");
            let key = self.channel_key(&name);
            self.saved.insert(key, gone.state);
        }
    }

    /// Books one sample into its channel's counter: its reading, or `None` for a read the
    /// counter holds as suspect (not published: the next read says what it was), or a
    /// channel not declared. A gauge's sample is its reading as it is.
    fn book(&mut self, s: &Sample) -> Option<Reading> {
        let Some(ch) = self.channels.get_mut(s.channel) else {
            tracing::debug!(device = %self.name, channel = s.channel, "a sample of a channel not declared; ignored");
            return None;
        };
        if let Value::Gauge(value) = &s.value {
            return Some(ch.measured(&self.name, s, value.clone()));
        }
        let (Some(counter), Some(count)) = (ch.counter.as_mut(), s.value.count()) else {
            return None;
        };
        s.value.shape(&mut counter.spec);
        let first = counter.state.count.is_none();
        let update = if s.starts_over {
            // The total stays; the count before the start was never this channel's to count.
            counter.rebase(count, s.at.stamp, Event::Reset)
        } else {
            let Some(update) = counter.update(count, s.at.stamp) else {
                tracing::debug!(device = %self.name, channel = %ch.name, count, "implausible count held until the next read");
                return None;
            };
            update
        };
        if first && matches!(s.value, Value::Register { .. }) {
            first_meter_reading(counter, ch.units.as_deref(), count, s.at.stamp.wall_ms);
        }
        Some(ch.reading(&self.name, s, count, update))
    }

    /// Books what a clear or preset did: the counts read before the write (as a poll's), then
    /// each channel written rebased on its read-back, booking the pulses counted between the
    /// write and the read-back, so the write itself never moves a total. A read-back further
    /// from what was written than the input could count meanwhile is an error, and counting
    /// goes on from what is there. The result is the count read back for a single channel.
    pub fn book_command(
        &mut self,
        executed: Executed,
    ) -> (Vec<Reading>, Result<Option<i64>, CommandError>) {
        let mut readings: Vec<Reading> = executed
            .before
            .iter()
            .filter_map(|s| self.book(s))
            .collect();
        if let Some(e) = executed.failed {
            return (readings, Err(e));
        }
        let mut mismatch = None;
        let mut single = None;
        for w in &executed.written {
            let Some((reading, read_back)) = self.rebase(w) else {
                continue;
            };
            if let Err(e) = read_back {
                mismatch.get_or_insert(e);
            }
            single = Some(reading.count);
            readings.push(reading);
        }
        let result = match mismatch {
            Some(e) => Err(e),
            None => Ok(single.filter(|_| executed.written.len() == 1)),
        };
        (readings, result)
    }

    /// Rebases the channel `w` wrote on what was read back: its reading, and whether the
    /// read-back is what was written.
    fn rebase(&mut self, w: &Written) -> Option<(Reading, Result<(), CommandError>)> {
        let back = w.read_back.as_ref()?;
        let ch = self.channels.get_mut(w.channel)?;
        let (counter, got) = (ch.counter.as_mut()?, back.value.count()?);
        let (expected, event) = (w.wrote.value(), w.wrote.event());
        // Pulses keep coming while the gateway writes: allow what the input can count meanwhile.
        let slack = counter.spec.plausible(w.elapsed_ms);
        let (update, checked) = if (got - expected).abs() > slack {
            // The write did not take as asked: book nothing, go on from what is there.
            let update = counter.rebase(got, back.at.stamp, event);
            (update, Err(CommandError::ReadBack { expected, got }))
        } else {
            // Pulses counted between the write and the read-back are booked.
            let update = counter.rebase_from(expected, got, back.at.stamp, event);
            (update, Ok(()))
        };
        Some((ch.reading(&self.name, back, got, update), checked))
    }
}

impl<P: DeviceState> DeviceRt<P> {
    /// Books the samples of one poll into the counters: the readings to publish, each fed to
    /// the metrics. A reset the counters find is told to the driver's device state (the device
    /// may have restarted).
    pub fn book_poll(&mut self, samples: Vec<Sample>) -> Vec<Reading> {
        let mut readings = Vec::with_capacity(samples.len());
        let mut reset = false;
        for s in &samples {
            let Some(reading) = self.book(s) else {
                continue;
            };
            reset |= !s.starts_over && reading.update.event == Some(Event::Reset);
            self.metrics.reading(&reading);
            readings.push(reading);
        }
        if reset {
            self.proto.reset_found();
        }
        readings
    }
}

#[cfg(test)]
#[path = "book_tests.rs"]
mod book_tests;

//! A bus's readings → output, by each channel's publish policy and its device's payload shape.
//!
//! The policy itself is pure ([`crate::config::policy`]); this is where it meets the device:
//! a skipped reading hands its sequence number back to the counter, so `seq` counts published
//! readings only (and the saved state agrees), and its delta rides on the next published one.

use std::collections::HashMap;
use std::sync::Arc;

use super::device::DeviceRt;
use crate::config::Gateway;
use crate::config::policy::{Gate, PayloadMode, Policy, PolicyOverride};
use crate::config::units::ChannelUnits;
use crate::metering::{Clock, Period, Read, Record};
use crate::reading::{IntervalRecord, Output, Reading, unix_ms};

/// One channel's gate, policy, units and interval periods.
struct ChannelOut {
    gate: Gate,
    policy: Policy,
    units: Option<Arc<ChannelUnits>>,
    periods: Vec<(Period, Arc<str>)>,
}

/// The publish state of every channel of a bus.
pub(super) struct Emitter {
    policy: PolicyOverride,
    payload: PayloadMode,
    channels: HashMap<(Arc<str>, Arc<str>), ChannelOut>,
    /// `gateway.timezone` and `gateway.intervals`.
    clock: Clock,
    gateway: Gateway,
}

impl Emitter {
    pub(super) fn new(gateway: &Gateway) -> Emitter {
        Emitter {
            policy: gateway.publish,
            payload: gateway.payload,
            channels: HashMap::new(),
            clock: gateway.clock.clone(),
            gateway: gateway.clone(),
        }
    }

    /// The next interval boundary after `now_ms` of any channel of `d` (Unix ms).
    pub(super) fn next_boundary<P>(&self, d: &DeviceRt<P>, now_ms: i64) -> Option<i64> {
        let gateway = self.gateway.intervals.as_deref();
        let mut periods: Vec<&Period> = d
            .channels
            .iter()
            .filter(|c| c.counter.is_some())
            .flat_map(|c| d.config.intervals_of(gateway, &c.name))
            .collect();
        // Channels mostly share their periods: each is reckoned once.
        periods.sort_by_key(|p| p.ms());
        periods.dedup_by_key(|p| p.ms());
        periods.iter().map(|p| self.clock.next(p, now_ms)).min()
    }

    /// Books each reading into its channel's intervals: the records they close (before the
    /// publish policy, which may skip a reading but never its pulses).
    fn intervals<P>(&mut self, d: &mut DeviceRt<P>, readings: &[Reading]) -> Vec<Output> {
        let mut out = Vec::new();
        for r in readings {
            let c = self.channel(d, &r.channel);
            if c.periods.is_empty() {
                continue;
            }
            let (periods, units) = (c.periods.clone(), c.units.clone());
            let device = d.name.clone();
            let channel = d.channels.iter_mut().find(|c| c.name == r.channel);
            let Some(counter) = channel.and_then(|c| c.counter.as_mut()) else {
                continue;
            };
            let read = Read {
                at_ms: unix_ms(r.ts) as i64,
                total: r.update.total,
                event: r.update.event,
            };
            let shortest = periods
                .iter()
                .min_by_key(|(p, _)| p.ms())
                .map(|(_, t)| t.clone());
            let open = |s: &crate::counter::CounterState| {
                let st = shortest.as_deref().and_then(|t| s.intervals.get(t));
                st.and_then(|st| st.open.as_ref()).map(|o| o.start_ms)
            };
            let before = open(&counter.state);
            let mut closed = Vec::new();
            for (period, text) in periods {
                let state = counter.state.intervals.entry(text.to_string());
                if let Some(record) = state.or_default().observe(&self.clock, &period, read) {
                    closed.push((text, record));
                }
            }
            let booking = self.gateway.tariffs.is_some() || self.gateway.billing.is_some();
            if let Some(shortest) = shortest.as_ref().filter(|_| booking) {
                let books = crate::metering::account::Books {
                    clock: &self.clock,
                    calendar: self.gateway.tariffs.as_deref(),
                    billing: self.gateway.billing.as_deref(),
                };
                let shortest = crate::metering::account::Shortest {
                    period: shortest,
                    fresh: before.is_none(),
                    opened: open(&counter.state).filter(|_| before.is_none()),
                };
                let account = counter.state.account.get_or_insert_with(Default::default);
                account.book(&books, &shortest, read, &mut closed);
            }
            for (text, record) in closed {
                out.push(interval(
                    &device,
                    r.channel.clone(),
                    text,
                    record,
                    units.clone(),
                ));
            }
        }
        out
    }

    /// The output of a record of `d`'s `channel` closed in an earlier run, sent again at start.
    pub(super) fn record<P>(
        &mut self,
        d: &DeviceRt<P>,
        channel: &str,
        period: &str,
        record: Record,
    ) -> Output {
        let channel: Arc<str> = Arc::from(channel);
        let units = self.channel(d, &channel).units.clone();
        interval(&d.name, channel, Arc::from(period), record, units)
    }

    fn channel<P>(&mut self, d: &DeviceRt<P>, channel: &Arc<str>) -> &mut ChannelOut {
        let gateway = self.policy;
        let all = &self.gateway;
        self.channels
            .entry((d.name.clone(), channel.clone()))
            .or_insert_with(|| {
                let config = d.config.channels.get(&**channel);
                let policy = gateway
                    .then(&d.config.publish)
                    .then(&config.map(|c| c.publish).unwrap_or_default())
                    .policy();
                // The config's scale wins over what the driver declared (a meter register's
                // step, a gauge's unit).
                let declared = d.channels.iter().find(|c| c.name == *channel);
                let units = config
                    .filter(|c| c.units.scale.is_some())
                    .map(|c| Arc::new(c.units.clone()))
                    .or_else(|| declared.and_then(|c| c.units.clone()))
                    .map(|u| named(u, config.and_then(|c| c.units.obis)));
                let periods = d
                    .config
                    .intervals_of(all.intervals.as_deref(), channel)
                    .iter()
                    .map(|p| (p.clone(), Arc::from(p.text())))
                    .collect();
                ChannelOut {
                    gate: Gate::default(),
                    policy,
                    units,
                    periods,
                }
            })
    }

    /// What the policy publishes of `readings` (one poll or one command of device `d`), as the
    /// outputs to send (the bus sends them once their seq is durable, see `saver`).
    /// With `payload = "device"`, a poll in which any channel is due publishes all of them in
    /// one message.
    pub(super) fn emit<P>(&mut self, d: &mut DeviceRt<P>, readings: Vec<Reading>) -> Vec<Output> {
        let records = self.intervals(d, &readings);
        let payload = d.config.payload.unwrap_or(self.payload);
        let wants: Vec<bool> = readings
            .iter()
            .map(|r| {
                let c = self.channel(d, &r.channel);
                c.gate.wants(&c.policy, unix_ms(r.ts), gated(r), &r.update)
            })
            .collect();
        let all = payload == PayloadMode::Device && wants.iter().any(|w| *w);
        let mut published = Vec::with_capacity(readings.len());
        for (mut r, want) in readings.into_iter().zip(wants) {
            let c = self.channel(d, &r.channel);
            if want || all {
                r.update = c.gate.publish(unix_ms(r.ts), gated(&r), &r.update);
                r.units = c.units.clone();
                r.meter = d
                    .channels
                    .iter()
                    .find(|ch| ch.name == r.channel)
                    .and_then(|ch| ch.counter.as_ref()?.state.meter.clone());
                published.push(r);
            } else {
                c.gate.skip(&r.update);
                d.withdraw_seq(&r.channel);
            }
        }
        // One event for the poll: how it goes on the wire (a message per channel or per device)
        // is the format's business. The records it closed follow it.
        let mut outputs = Vec::with_capacity(1 + records.len());
        if !published.is_empty() {
            outputs.push(Output::DeviceReadings {
                device: d.name.clone(),
                readings: published,
            });
        }
        outputs.extend(records);
        outputs
    }
}

/// What the publish policy compares between readings: the count, or a gauge's value (so
/// `publish = "change"` publishes a gauge when its value changes).
fn gated(r: &Reading) -> i64 {
    use std::hash::{Hash, Hasher};
    let Some(m) = &r.measured else {
        return r.count;
    };
    let mut h = std::collections::hash_map::DefaultHasher::new();
    m.to_string().hash(&mut h);
    h.finish() as i64
}

fn interval(
    device: &Arc<str>,
    channel: Arc<str>,
    period: Arc<str>,
    record: Record,
    units: Option<Arc<ChannelUnits>>,
) -> Output {
    Output::Interval(Box::new(IntervalRecord {
        device: device.clone(),
        channel,
        period,
        record,
        units,
    }))
}

/// A meter's declared units with the OBIS name the config gives its channel.
fn named(units: Arc<ChannelUnits>, obis: Option<crate::metering::obis::Obis>) -> Arc<ChannelUnits> {
    match obis {
        Some(o) if units.obis != Some(o) => Arc::new(ChannelUnits {
            obis: Some(o),
            ..(*units).clone()
        }),
        _ => units,
    }
}

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
use crate::reading::{Output, Reading, unix_ms};

/// One channel's gate, policy and units.
struct ChannelOut {
    gate: Gate,
    policy: Policy,
    units: Option<Arc<ChannelUnits>>,
}

/// The publish state of every channel of a bus.
pub(super) struct Emitter {
    policy: PolicyOverride,
    payload: PayloadMode,
    channels: HashMap<(Arc<str>, Arc<str>), ChannelOut>,
}

impl Emitter {
    pub(super) fn new(gateway: &Gateway) -> Emitter {
        Emitter {
            policy: gateway.publish,
            payload: gateway.payload,
            channels: HashMap::new(),
        }
    }

    fn channel<P>(&mut self, d: &DeviceRt<P>, channel: &Arc<str>) -> &mut ChannelOut {
        let gateway = self.policy;
        self.channels
            .entry((d.name.clone(), channel.clone()))
            .or_insert_with(|| {
                let config = d.config.channels.get(&**channel);
                let policy = gateway
                    .then(&d.config.publish)
                    .then(&config.map(|c| c.publish).unwrap_or_default())
                    .policy();
                let units = config
                    .filter(|c| c.units.scale.is_some())
                    .map(|c| Arc::new(c.units.clone()));
                ChannelOut {
                    gate: Gate::default(),
                    policy,
                    units,
                }
            })
    }

    /// What the policy publishes of `readings` (one poll or one command of device `d`), as the
    /// outputs to send (the bus sends them once their seq is durable, see `saver`).
    /// With `payload = "device"`, a poll in which any channel is due publishes all of them in
    /// one message.
    pub(super) fn emit<P>(&mut self, d: &mut DeviceRt<P>, readings: Vec<Reading>) -> Vec<Output> {
        let payload = d.config.payload.unwrap_or(self.payload);
        let wants: Vec<bool> = readings
            .iter()
            .map(|r| {
                let c = self.channel(d, &r.channel);
                c.gate.wants(&c.policy, unix_ms(r.ts), r.count, &r.update)
            })
            .collect();
        let all = payload == PayloadMode::Device && wants.iter().any(|w| *w);
        let mut published = Vec::with_capacity(readings.len());
        for (mut r, want) in readings.into_iter().zip(wants) {
            let c = self.channel(d, &r.channel);
            if want || all {
                r.update = c.gate.publish(unix_ms(r.ts), r.count, &r.update);
                r.units = c.units.clone();
                published.push(r);
            } else {
                c.gate.skip(&r.update);
                d.withdraw_seq(&r.channel);
            }
        }
        // One event for the poll: how it goes on the wire (a message per channel or per device)
        // is the format's business.
        if published.is_empty() {
            return Vec::new();
        }
        vec![Output::DeviceReadings {
            device: d.name.clone(),
            readings: published,
        }]
    }
}

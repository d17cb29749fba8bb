//! Writing the command register of counters that start and stop by register (ZH-YX1600): a
//! stopped counter started in its configured direction, a paused one resumed where configured,
//! the power-on state set once per run. What the command word means is `run_state.rs`.

use super::device::ModbusDevice;
use super::link::Link;
use super::run_state::{RunState, run_state, start_code};
use crate::bus::device::DeviceRt;
use crate::config::Run;
use crate::profile::ChannelKind;
use crate::sample::Sample;

impl DeviceRt<ModbusDevice> {
    /// Resumes channel `i`, found paused, where configured (`resume_paused`): the count was
    /// kept, so nothing is rebased; the next reads count on.
    pub(super) async fn resume_paused(&mut self, link: &mut Link, i: usize) {
        let ch = &self.proto.channels[i];
        let Some(code) = start_code(&ch.spec, ch.run) else {
            return;
        };
        let (name, register) = (ch.name.clone(), ch.spec.clear.register);
        let timeout = self.timeout_for(link, 1);
        match link
            .write_register(self.proto.unit, register, code, timeout)
            .await
        {
            Ok(Ok(())) => {
                tracing::info!(device = %self.name, channel = %name, "counter was paused; resumed with {code:#06x} as configured (resume_paused)")
            }
            other => {
                tracing::warn!(device = %self.name, channel = %name, "paused counter not resumed: {other:?}")
            }
        }
    }

    /// Sets the power-on state of channels configured with `power_on = true` to their run
    /// direction, once per run and only where it differs: the module keeps it in flash and
    /// applies it after its next restart, so it counts after a power cut without waiting for
    /// the gateway. Failures are logged and tried again at the next slow poll.
    pub(super) async fn set_power_on(&mut self, link: &mut Link) {
        let timeout = self.timeout_for(link, 1);
        for i in 0..self.proto.channels.len() {
            let ch = &self.proto.channels[i];
            let configured = self
                .config
                .channels
                .get(&*ch.name)
                .is_some_and(|c| c.power_on);
            let (Some(p), true, false) = (ch.spec.power_on, configured, ch.power_on_done) else {
                continue;
            };
            let down = ch.run == Run::Down && ch.spec.kind == ChannelKind::Counter;
            let name = ch.name.clone();
            let word = match link.read(self.proto.unit, p.address, 1, timeout).await {
                Ok(Ok(w)) => w[0],
                other => {
                    tracing::warn!(device = %self.name, channel = %name, "power-on state not read: {other:?}");
                    continue;
                }
            };
            let wanted = p.apply(word, down);
            if wanted != word {
                match link
                    .write_register(self.proto.unit, p.address, wanted, timeout)
                    .await
                {
                    Ok(Ok(())) => {
                        tracing::info!(device = %self.name, channel = %name, "power-on state set: register {:#06x} {word:#06x} → {wanted:#06x}; the module counts by itself after its next restart", p.address)
                    }
                    other => {
                        tracing::warn!(device = %self.name, channel = %name, "power-on state not set: {other:?}");
                        continue;
                    }
                }
            }
            self.proto.channels[i].power_on_done = true;
        }
    }

    /// Starts the channel of `found`, a sample of it found stopped: writes the start code, and
    /// returns the sample as one that starts over (the core books the restart: the total stays;
    /// the count since power-up or the stop was cleared by the module). `None` when it is left
    /// stopped or the write failed (tried again next poll).
    pub(super) async fn start_stopped(&mut self, link: &mut Link, found: Sample) -> Option<Sample> {
        let (i, count) = (found.channel, found.value.count()?);
        let ch = &self.proto.channels[i];
        let code = start_code(&ch.spec, ch.run)?;
        let register = ch.spec.clear.register;
        let timeout = self.timeout_for(link, 1);
        match link
            .write_register(self.proto.unit, register, code, timeout)
            .await
        {
            Ok(Ok(())) => {}
            failed => {
                let why = match failed {
                    Ok(Err(e)) => format!("the module refused: {e:?}"),
                    Err(e) => e.to_string(),
                    Ok(Ok(())) => unreachable!(),
                };
                tracing::warn!(device = %self.name, channel = %self.proto.channels[i].name, "counter is stopped and could not be started: {why}");
                return None;
            }
        }
        let ch = &mut self.proto.channels[i];
        tracing::warn!(
            device = %self.name,
            channel = %ch.name,
            "counter was stopped (command register {register:#06x} read {:#06x}: module power-up or a stop by another master); started it with {code:#06x}; pulses before the start were not counted by the module",
            ch.spec.clear.code
        );
        if let RunState::Running(d) = run_state(&ch.spec, code) {
            ch.wrap.direction = d;
        }
        let wrap = ch.wrap;
        self.proto.module_restarted();
        let started = Sample::count(i, found.at, count, wrap);
        Some(started.with_rates(found.freq_hz, found.rpm).starting_over())
    }
}

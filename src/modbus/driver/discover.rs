//! Discovery of a Modbus device: its identity (checked at discovery and after a reset), the
//! work modes and slow registers that give its channels, and the channels built from them (and
//! declared to the bus core, which counts them).

use std::sync::Arc;

use tokio::time::Instant;
use tokio_modbus::ExceptionCode;

use super::device::{ModbusChannel, ModbusDevice, ModbusError, PollError};
use super::identity::{Verdict, judge};
use super::link::Link;
use crate::bus::device::DeviceRt;
use crate::config::{ChannelConfig, Run};
use crate::decode::decode;
use crate::profile::{ChannelKind, ChannelSpec, Register, ValueType};
use crate::sample::{Channel, Counting, Direction, Wrap};

impl DeviceRt<ModbusDevice> {
    /// Discovery when due (identity, then the work modes and slow registers that give the
    /// channels), and the slow registers' refresh.
    pub async fn discover(
        &mut self,
        link: &mut Link,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), PollError> {
        if self.proto.identify_due {
            self.check_identity(link).await?;
        }
        let slow_due = self
            .proto
            .last_slow
            .is_none_or(|t| t.elapsed() >= self.proto.slow_every);
        if self.proto.modes.is_none() {
            // Without the work modes there are no channels: discovery must succeed.
            self.read_slow(link, preempt).await?;
        } else if slow_due {
            // Once discovered, a failed refresh of the slow registers keeps the values known
            // and tries again a slow interval later; the counts matter more.
            match self.read_slow(link, preempt).await {
                Err(PollError::Preempted) => return Err(PollError::Preempted),
                Err(e) => {
                    tracing::debug!(device = %self.name, "slow registers not refreshed: {e}");
                    self.proto.last_slow = Some(Instant::now());
                }
                Ok(()) => {}
            }
        }
        Ok(())
    }

    /// Checks the module's identity (due at discovery and after a reset).
    async fn check_identity(&mut self, link: &mut Link) -> Result<(), PollError> {
        match self.identify(link).await? {
            Verdict::Confirmed => {}
            Verdict::Unidentified => {
                if !std::mem::replace(&mut self.proto.unidentified_warned, true) {
                    tracing::warn!(device = %self.name, model = %self.config.model, "the module refuses its identification registers; accepted as configured");
                }
            }
            Verdict::Wrong(why) => return Err(PollError::Protocol(ModbusError::WrongModel(why))),
        }
        self.proto.identify_due = false;
        if let Some(was) = self.out_of_service.take() {
            tracing::info!(device = %self.name, "the module is now the configured model (was: {was})");
            self.metrics.wrong_model(false);
        }
        Ok(())
    }

    /// Reads work modes (and with them the channel set) and pulses per revolution.
    async fn read_slow(
        &mut self,
        link: &mut Link,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), PollError> {
        let mode_regs = self.profile.mode_registers();
        let word = |address| Register {
            address,
            ty: ValueType::U16,
        };
        // The mode words, then the partner words that must agree with them.
        let regs: Vec<Register> = mode_regs
            .iter()
            .map(|m| word(m.address))
            .chain(mode_regs.iter().filter_map(|m| m.partner.map(word)))
            .collect();
        let snap = self.read_registers(link, &regs, preempt).await?;
        // Masked: bits outside the mask (a counter's power-on state) are no work mode.
        let masks = mode_regs.iter().map(|m| m.mask).chain(
            mode_regs
                .iter()
                .filter(|m| m.partner.is_some())
                .map(|m| m.mask),
        );
        let modes: Vec<u16> = regs
            .iter()
            .zip(masks)
            .filter_map(|(r, mask)| snap.get(r).map(|(w, _)| w[0] & mask))
            .collect();
        let mut specs = self
            .profile
            .channels(&modes)
            .map_err(|e| PollError::Profile(e.to_string()))?;
        let value = |a| snap.get(&word(a)).map(|(w, _)| w[0]);
        // (mode word, description) of each pair whose two words disagree.
        let mismatched: Vec<(u16, String)> = mode_regs
            .iter()
            .filter_map(|m| {
                let (own, partner) = (value(m.address)?, value(m.partner?)?);
                ((own ^ partner) & m.mask != 0).then(|| {
                    let why = format!(
                        "mode words {:#06x} = {own:#06x} and {:#06x} = {partner:#06x} disagree on bits {:#06x}",
                        m.address,
                        m.partner.expect("checked"),
                        m.mask
                    );
                    (m.address, why)
                })
            })
            .collect();
        // The module does not count such a pair: publish no channel that never moves.
        specs.retain(|c| mismatched.iter().all(|(a, _)| *a != c.mode_register));
        let described: Vec<&str> = mismatched.iter().map(|(_, w)| w.as_str()).collect();
        let name = self.name.clone();
        self.proto
            .set_mismatch(&name, (!described.is_empty()).then(|| described.join("; ")));
        if self.proto.modes.as_ref() != Some(&modes) {
            if self.proto.modes.is_some() {
                tracing::warn!(device = %self.name, ?modes, "work mode changed; channels rebuilt");
            }
            self.build_channels(specs);
            self.proto.modes = Some(modes);
        }
        self.read_pprs(link, preempt).await?;
        self.read_windows(link, preempt).await?;
        self.set_power_on(link).await;
        self.replan_with_turnaround(link);
        self.proto.last_slow = Some(Instant::now());
        Ok(())
    }

    /// Reads the pulses per revolution of the channels whose module has a register for it (a
    /// configured `ppr` wins).
    async fn read_pprs(
        &mut self,
        link: &mut Link,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), PollError> {
        let ppr_regs: Vec<Register> = self
            .proto
            .channels
            .iter()
            .filter_map(|c| c.spec.ppr)
            .collect();
        if ppr_regs.is_empty() {
            return Ok(());
        }
        let snap = self.read_registers(link, &ppr_regs, preempt).await?;
        let order = self.profile.word_order;
        for ch in &mut self.proto.channels {
            let configured = self.config.channels.get(&*ch.name).and_then(|c| c.ppr);
            let read = ch
                .spec
                .ppr
                .and_then(|r| snap.get(&r))
                .map(|(w, _)| decode(w, ValueType::U16, order).as_f64());
            ch.ppr = configured.or(read.filter(|p| *p > 0.0));
        }
        Ok(())
    }

    /// Reads the counting windows of frequency registers that count pulses per window.
    async fn read_windows(
        &mut self,
        link: &mut Link,
        preempt: &(dyn Fn() -> bool + Sync),
    ) -> Result<(), PollError> {
        let regs: Vec<Register> = self
            .proto
            .channels
            .iter()
            .filter_map(|c| c.spec.freq_window.map(|w| w.register))
            .collect();
        if regs.is_empty() {
            return Ok(());
        }
        let snap = self.read_registers(link, &regs, preempt).await?;
        let order = self.profile.word_order;
        for mb in &mut self.proto.channels {
            let Some(w) = mb.spec.freq_window else {
                continue;
            };
            let Some((words, _)) = snap.get(&w.register) else {
                continue;
            };
            let raw = decode(words, w.register.ty, order).as_i64() as u64;
            let seconds = w.seconds(raw);
            if seconds.is_none() && !std::mem::replace(&mut mb.window_bad, true) {
                tracing::warn!(device = %self.name, channel = %mb.name, register = w.register.address, raw, "the counting window register reads a value that is no window; frequency not published");
            }
            mb.window_bad = seconds.is_none();
            mb.window_s = seconds;
        }
        Ok(())
    }

    /// Builds the channels of the current work mode and declares them to the bus core, which
    /// keeps each counter across the rebuild, and keeps the state of a channel the new mode does
    /// not have (or a disabled one) for when it comes back.
    fn build_channels(&mut self, specs: Vec<ChannelSpec>) {
        let mut declared = Vec::with_capacity(specs.len());
        self.proto.channels.clear();
        for spec in specs {
            let overrides = self
                .config
                .channels
                .get(&spec.name)
                .cloned()
                .unwrap_or_default();
            if !overrides.enabled {
                continue;
            }
            let name: Arc<str> = Arc::from(spec.name.as_str());
            let wrap = wrap_of(&spec, &overrides);
            declared.push(Channel {
                name: name.clone(),
                kind: spec.kind,
                counting: Counting::Count {
                    wrap,
                    max_rate_hz: overrides.max_rate_hz.unwrap_or(spec.max_rate_hz),
                },
                units: None,
            });
            self.proto.channels.push(ModbusChannel {
                name,
                command: super::run_state::command_register(&spec),
                wrap,
                ppr: overrides.ppr,
                spec,
                window_s: None,
                window_bad: false,
                power_on_done: false,
                run: overrides.run,
                resume_paused: overrides.resume_paused,
            });
        }
        self.declare(declared);
        self.proto.fast = self
            .proto
            .channels
            .iter()
            .flat_map(|c| c.spec.polled())
            .collect();
    }

    /// Reads the identification registers and judges them. Link failures (no answer) are
    /// returned as such: they say nothing about the model.
    pub(super) async fn identify(&mut self, link: &mut Link) -> Result<Verdict, PollError> {
        let Some(expected) = self.profile.identify.clone() else {
            return Ok(Verdict::Confirmed);
        };
        let own = self
            .read_identity(link, expected.0, expected.1.len())
            .await?;
        if matches!(&own, Ok(w) if *w == expected.1) {
            return Ok(Verdict::Confirmed);
        }
        let known = self.proto.known.clone();
        let mut others = Vec::new();
        for id in known
            .iter()
            .filter(|i| i.words != expected.1 || i.address != expected.0)
        {
            let answer = if id.address == expected.0 && id.words.len() == expected.1.len() {
                own.clone()
            } else {
                self.read_identity(link, id.address, id.words.len()).await?
            };
            if answer.as_ref().is_ok_and(|w| *w == id.words) {
                others.push(id);
            }
        }
        Ok(judge(&self.config.model, &expected, &own, &others))
    }

    async fn read_identity(
        &mut self,
        link: &mut Link,
        address: u16,
        len: usize,
    ) -> Result<Result<Vec<u16>, ExceptionCode>, PollError> {
        let len = len as u16;
        let timeout = self.timeout_for(link, len);
        let mut tries = 0;
        loop {
            match link.read(self.proto.unit, address, len, timeout).await {
                // Lost to noise: asked again as a poll's read is (see `asks_again`).
                Err(e) if self.asks_again(&e, tries) => tries += 1,
                other => return Ok(other?),
            }
        }
    }
}

/// How a channel's count wraps: at its register's width; encoders both ways; inputs counting
/// on their own only up, or in the direction the gateway runs them (ZH-YX1600 counters are
/// signed and can count down).
fn wrap_of(spec: &ChannelSpec, config: &ChannelConfig) -> Wrap {
    let signed = matches!(spec.count.ty, ValueType::I32 | ValueType::I16);
    let direction = match (spec.kind, signed, config.run) {
        (ChannelKind::Encoder, ..) => Direction::Both,
        (ChannelKind::Counter, false, _) => Direction::Up,
        (ChannelKind::Counter, true, _) if spec.clear.restart.is_empty() => Direction::Both,
        (ChannelKind::Counter, true, Run::Up) => Direction::Up,
        (ChannelKind::Counter, true, Run::Down) => Direction::Down,
        (ChannelKind::Counter, true, Run::Leave) => Direction::Both,
    };
    Wrap {
        bits: 16 * u32::from(spec.count.ty.words()),
        direction,
    }
}

//! Run state of counters that start and stop by register (ZH-YX1600): the datasheet's counters
//! are stopped after power-up (mode word pAuto 0, the factory value) and a stop by anyone clears
//! them. A counter found stopped is started in its configured direction within the same poll,
//! and its reading says so (`reset`); `run = "leave"` leaves it to another system; a paused
//! counter is left paused.

use super::device::ModbusDevice;
use super::link::Link;
use crate::bus::device::{At, DeviceRt};
use crate::config::Run;
use crate::counter::{Direction, Event};
use crate::profile::{ChannelKind, ChannelSpec, Register};
use crate::reading::Reading;

/// The command register of a channel that has one.
pub(super) fn command_register(spec: &ChannelSpec) -> Option<Register> {
    spec.command_register()
}

/// What a command word means for a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub(super) enum RunState {
    Stopped,
    Running(Direction),
    /// Paused: the count is kept, nothing is counted.
    Paused,
    /// A value the profile does not name: left alone.
    Other,
}

/// Reads a command word: the profile's clear code is "stopped" (stop and clear), its restart
/// codes run up and (the second) down; a quadrature counter's direction is the phase's.
pub(super) fn run_state(spec: &ChannelSpec, word: u16) -> RunState {
    let both = spec.kind == ChannelKind::Encoder;
    if word == spec.clear.code {
        RunState::Stopped
    } else if spec.clear.restart.first() == Some(&word) {
        RunState::Running(if both { Direction::Both } else { Direction::Up })
    } else if spec.clear.restart.get(1) == Some(&word) {
        RunState::Running(if both {
            Direction::Both
        } else {
            Direction::Down
        })
    } else if spec.clear.pause == Some(word) {
        RunState::Paused
    } else {
        RunState::Other
    }
}

/// The code that starts a channel as configured; `None` for `leave`.
pub(super) fn start_code(spec: &ChannelSpec, run: Run) -> Option<u16> {
    let up = *spec.clear.restart.first()?;
    match run {
        Run::Leave => None,
        Run::Up => Some(up),
        // Quadrature counters only take the first code (the phase gives the direction).
        Run::Down if spec.kind == ChannelKind::Encoder => Some(up),
        Run::Down => Some(spec.clear.restart.get(1).copied().unwrap_or(up)),
    }
}

impl DeviceRt<ModbusDevice> {
    /// Resumes channel `i`, found paused, where configured (`resume_paused`): the count was
    /// kept, so nothing is rebased; the next reads count on.
    pub(super) async fn resume_paused(&mut self, link: &mut Link, i: usize) {
        let ch = &self.channels[i];
        let Some(code) = start_code(&ch.spec, self.proto.channels[i].run) else {
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
        for i in 0..self.channels.len() {
            let ch = &self.channels[i];
            let configured = self
                .config
                .channels
                .get(&*ch.name)
                .is_some_and(|c| c.power_on);
            let done = self.proto.channels[i].power_on_done;
            let (Some(p), true, false) = (ch.spec.power_on, configured, done) else {
                continue;
            };
            let down =
                self.proto.channels[i].run == Run::Down && ch.spec.kind == ChannelKind::Counter;
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

    /// Starts channel `i`, found stopped with `count` at `at`: writes the start code, then books
    /// the restart (the total stays; the count since power-up or the stop was cleared by the
    /// module). `None` when it is left stopped or the write failed (tried again next poll).
    pub(super) async fn start_stopped(
        &mut self,
        link: &mut Link,
        i: usize,
        count: i64,
        at: At,
        freq_hz: Option<f64>,
        rpm: Option<f64>,
    ) -> Option<Reading> {
        let ch = &self.channels[i];
        let code = start_code(&ch.spec, self.proto.channels[i].run)?;
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
                tracing::warn!(device = %self.name, channel = %self.channels[i].name, "counter is stopped and could not be started: {why}");
                return None;
            }
        }
        let ch = &mut self.channels[i];
        tracing::warn!(
            device = %self.name,
            channel = %ch.name,
            "counter was stopped (command register {register:#06x} read {:#06x}: module power-up or a stop by another master); started it with {code:#06x}; pulses before the start were not counted by the module",
            ch.spec.clear.code
        );
        if let RunState::Running(d) = run_state(&ch.spec, code) {
            ch.counter.spec.direction = d;
        }
        let update = ch.counter.rebase(count, at.stamp, Event::Reset);
        self.proto.module_restarted();
        let ch = &self.channels[i];
        Some(ch.reading(&self.name, at.wall, count, freq_hz, rpm, update))
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::profile::Profiles;

    fn zh(modes: &[u16], name: &str) -> ChannelSpec {
        let p = Profiles::builtin().get("zh-yx1600").unwrap();
        p.channels(modes)
            .unwrap()
            .into_iter()
            .find(|c| c.name == name)
            .unwrap()
    }

    #[test]
    fn zh_yx1600_command_words_read_as_the_datasheet_says() {
        let di1 = zh(&[0], "di1");
        assert_eq!(run_state(&di1, 0x0000), RunState::Stopped);
        assert_eq!(run_state(&di1, 0x0001), RunState::Paused);
        assert_eq!(run_state(&di1, 0x0042), RunState::Other);
        assert_eq!(run_state(&di1, 0x00A2), RunState::Running(Direction::Up));
        assert_eq!(run_state(&di1, 0x00A3), RunState::Running(Direction::Down));
        assert_eq!(command_register(&di1).unwrap().address, 0x1100);
        assert_eq!(command_register(&zh(&[0], "di2")).unwrap().address, 0x1101);
    }

    #[test]
    fn a_stopped_counter_is_started_as_configured_and_quadrature_only_with_0xa2() {
        let di1 = zh(&[0], "di1");
        assert_eq!(start_code(&di1, Run::Up), Some(0x00A2));
        assert_eq!(start_code(&di1, Run::Down), Some(0x00A3));
        assert_eq!(start_code(&di1, Run::Leave), None);
        let pair = zh(&[2], "di1");
        assert_eq!(start_code(&pair, Run::Down), Some(0x00A2));
        assert_eq!(run_state(&pair, 0x00A2), RunState::Running(Direction::Both));
    }

    #[test]
    fn modules_without_a_command_register_have_no_run_state() {
        let p = Profiles::builtin().get("yl67").unwrap();
        for c in p.all_channels() {
            assert_eq!(command_register(&c), None);
            assert_eq!(start_code(&c, Run::Up), None);
        }
    }
}

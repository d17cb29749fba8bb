//! Run state of counters that start and stop by register (ZH-YX1600): the datasheet's counters
//! are stopped after power-up (mode word pAuto 0, the factory value) and a stop by anyone clears
//! them. A counter found stopped is started in its configured direction within the same poll,
//! and its reading says so (`reset`); `run = "leave"` leaves it to another system; a paused
//! counter is left paused. This file reads the command word (pure); `run_control.rs` writes it.

use crate::config::Run;
use crate::profile::{ChannelKind, ChannelSpec, Register};
use crate::sample::Direction;

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

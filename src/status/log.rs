//! The last things that happened, bounded, and how each is said to a technician. Pure.

use std::collections::VecDeque;

use super::view::EventView;
use crate::event::Event;
use crate::outcome::{CommandOutcome, ScanOutcome};

/// Entries kept.
pub const KEPT: usize = 100;

/// The last [`KEPT`] events, oldest first.
#[derive(Debug, Default, Clone)]
pub struct Log(VecDeque<EventView>);

impl Log {
    pub fn push(&mut self, event: EventView) {
        if self.0.len() >= KEPT {
            self.0.pop_front();
        }
        self.0.push_back(event);
    }

    /// Newest first.
    pub fn newest_first(&self) -> Vec<EventView> {
        self.0.iter().rev().cloned().collect()
    }
}

/// What a channel's counter event means.
pub fn channel_text(event: Event) -> &'static str {
    match event {
        Event::Rollover => "rollover: the count wrapped around its range",
        Event::Reset => {
            "reset: the count started over (module restarted, or cleared by someone else)"
        }
        Event::Cleared => "cleared by the gateway",
        Event::Preset => "preset by the gateway",
        Event::Gap => "gap: the delta covers a time the gateway or the module was away",
    }
}

/// What a device's status means.
pub fn status_text(status: &str) -> String {
    match status {
        "online" => "online: answering".to_string(),
        "offline" => "offline: stopped answering".to_string(),
        "wrong_model" => {
            "wrong_model: the module does not identify as the model configured".to_string()
        }
        "mode_mismatch" => {
            "mode_mismatch: the module's work mode is not the one configured".to_string()
        }
        other => format!("status {other}"),
    }
}

/// What became of a command.
pub fn command_text(c: &CommandOutcome) -> String {
    let op = c.op.as_deref().unwrap_or("command");
    let id =
        c.id.as_deref()
            .map(|i| format!(" (id {i})"))
            .unwrap_or_default();
    match &c.result {
        Ok(Some(count)) => format!("{op}{id} executed: count read back {count}"),
        Ok(None) => format!("{op}{id} executed"),
        Err(e) => format!("{op}{id} refused ({}): {e}", e.code()),
    }
}

/// What became of a scan.
pub fn scan_text(s: &ScanOutcome) -> String {
    match s {
        ScanOutcome::Report(r) => format!(
            "scan of bus {}: {} module(s) found, {} unit(s) asked in {:.1} s{}",
            r.bus,
            r.found.len(),
            r.asked,
            r.elapsed_ms as f64 / 1000.0,
            if r.complete {
                ""
            } else {
                ", cut short by its time limit"
            }
        ),
        ScanOutcome::Refused {
            bus, code, message, ..
        } => format!("scan of bus {bus} refused ({code}): {message}"),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn event(i: u64) -> EventView {
        EventView {
            at_ms: i,
            kind: "device",
            device: None,
            channel: None,
            text: i.to_string(),
        }
    }

    #[test]
    fn the_log_keeps_the_last_hundred_newest_first() {
        let mut log = Log::default();
        for i in 0..250 {
            log.push(event(i));
        }
        let all = log.newest_first();
        assert_eq!(all.len(), KEPT);
        assert_eq!(all[0].at_ms, 249);
        assert_eq!(all[KEPT - 1].at_ms, 150);
    }
}

//! Crash semantics of `seq`. Pure.
//!
//! A reading is published with the seq its channel reached; the state file holds the seq of
//! the last save. After SIGKILL the gateway resumes from the file, so without care it would
//! publish seqs it had already published, with different content. The ledger forbids that: a
//! channel may publish a seq only up to [`HEADROOM`] above the seq a completed (fsynced) save
//! holds; beyond it the bus saves first. After a start that did not follow a clean shutdown
//! every seq is moved [`HEADROOM`] ahead, past anything the crashed run could have published.
//! The first reading of each channel then carries `after_seq`: its delta counts from the reading
//! with that seq, so readings of the crashed run with a higher seq are superseded (their pulses
//! are in this delta). `total` is right either way.

use std::collections::{BTreeMap, HashMap};

use crate::counter::CounterState;

/// How far a channel's seq may run ahead of its last durable save.
pub const HEADROOM: u64 = 1000;

/// The highest seq each channel may publish, by channel key.
#[derive(Debug, Default)]
pub struct Ledger {
    limits: HashMap<String, u64>,
}

impl Ledger {
    /// A save of `channels` completed: their seqs are durable.
    pub fn durable(&mut self, channels: &BTreeMap<String, u64>) {
        for (key, seq) in channels {
            // An interval record goes out only once a save holds it closed: after a crash its
            // seq can never come again, nor its interval be closed a second time.
            let headroom = if is_record_key(key) { 0 } else { HEADROOM };
            let limit = seq.saturating_add(headroom);
            let e = self.limits.entry(key.clone()).or_insert(limit);
            *e = (*e).max(limit);
        }
    }

    /// Whether `seq` of channel `key` may be published now (a channel never saved may not).
    pub fn allows(&self, key: &str, seq: u64) -> bool {
        self.limits.get(key).is_some_and(|limit| seq <= *limit)
    }
}

/// The seqs in a state snapshot, by channel key; and the seq of the last record of each
/// interval period, by [`record_key`].
pub fn seqs(channels: &BTreeMap<String, CounterState>) -> BTreeMap<String, u64> {
    let mut out: BTreeMap<String, u64> = channels.iter().map(|(k, s)| (k.clone(), s.seq)).collect();
    for (key, s) in channels {
        for (period, st) in &s.intervals {
            out.insert(record_key(key, period), st.seq);
        }
    }
    out
}

/// The ledger's key of channel `key`'s interval records of `period`.
pub fn record_key(key: &str, period: &str) -> String {
    format!("{key}#interval/{period}")
}

fn is_record_key(key: &str) -> bool {
    key.contains("#interval/")
}

/// Moves every saved seq past what a crashed run could have published. Returns each channel's
/// seq before the move (the `after_seq` of its first reading).
pub fn after_crash(channels: &mut BTreeMap<String, CounterState>) -> BTreeMap<String, u64> {
    let mut before = BTreeMap::new();
    for (key, state) in channels.iter_mut() {
        before.insert(key.clone(), state.seq);
        state.seq = state.seq.saturating_add(HEADROOM);
    }
    before
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn an_interval_record_waits_for_the_save_that_closed_it_without_headroom() {
        let key = record_key("1/yl67/di0", "15min");
        let mut ledger = Ledger::default();
        assert!(!ledger.allows(&key, 1), "never saved");
        ledger.durable(&BTreeMap::from([(key.clone(), 3)]));
        assert!(ledger.allows(&key, 3));
        assert!(!ledger.allows(&key, 4), "not saved yet");
    }

    #[test]
    fn a_channel_never_saved_may_not_publish_until_a_save_completes() {
        let mut l = Ledger::default();
        assert!(!l.allows("1/yl67/enc0", 1));
        l.durable(&BTreeMap::from([("1/yl67/enc0".to_string(), 1)]));
        assert!(l.allows("1/yl67/enc0", 1));
        assert!(l.allows("1/yl67/enc0", 1 + HEADROOM));
        assert!(
            !l.allows("1/yl67/enc0", 2 + HEADROOM),
            "beyond the headroom: save first"
        );
    }

    #[test]
    fn after_a_crash_seq_starts_beyond_anything_the_crashed_run_could_publish() {
        let mut l = Ledger::default();
        let saved = BTreeMap::from([("k".to_string(), 60)]);
        l.durable(&saved);
        // The crashed run could publish up to 60 + HEADROOM.
        let mut channels = BTreeMap::from([(
            "k".to_string(),
            CounterState {
                seq: 60,
                ..CounterState::default()
            },
        )]);
        let before = after_crash(&mut channels);
        assert_eq!(before["k"], 60);
        assert!(channels["k"].seq + 1 > 60 + HEADROOM);
    }

    #[test]
    fn an_older_save_finishing_late_never_lowers_a_limit() {
        let mut l = Ledger::default();
        l.durable(&BTreeMap::from([("k".to_string(), 500)]));
        l.durable(&BTreeMap::from([("k".to_string(), 10)]));
        assert!(l.allows("k", 500 + HEADROOM));
    }
}

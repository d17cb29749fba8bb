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

use crate::counter::{CounterState, Handed};

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

/// Where a channel's readings resume after a start.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub struct Resume {
    /// After a crash: the seq the first reading's delta counts from (readings of the crashed
    /// run with a higher seq are superseded).
    pub after_seq: Option<u64>,
    /// Pulses in the saved total that no reading handed over carried (deltas the publish
    /// policy held for its next reading, readings a crash took while they waited for a save):
    /// the first reading's delta carries them.
    pub carry: i64,
    /// The last reading handed over, as the file says (until the first reading of this run).
    pub handed: Handed,
}

/// Where each saved channel resumes, by channel key (only channels with something to carry
/// or, after a crash, every one). After a crash (`crashed`) every saved seq is moved past what
/// the crashed run could have published.
pub fn resume(
    channels: &mut BTreeMap<String, CounterState>,
    crashed: bool,
) -> BTreeMap<String, Resume> {
    let mut out = BTreeMap::new();
    for (key, state) in channels.iter_mut() {
        let handed = state.handed.unwrap_or(Handed {
            seq: state.seq,
            total: state.total,
        });
        let after_seq = crashed.then_some(handed.seq);
        if crashed {
            state.seq = state.seq.saturating_add(HEADROOM);
        }
        let carry = state.total - handed.total;
        if after_seq.is_some() || carry != 0 {
            out.insert(
                key.clone(),
                Resume {
                    after_seq,
                    carry,
                    handed,
                },
            );
        }
    }
    out
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
        let resumed = resume(&mut channels, true);
        assert_eq!(resumed["k"].after_seq, Some(60));
        assert_eq!(resumed["k"].carry, 0);
        assert!(channels["k"].seq + 1 > 60 + HEADROOM);
    }

    fn handed_at(seq: u64, total: i64) -> BTreeMap<String, CounterState> {
        BTreeMap::from([(
            "k".to_string(),
            CounterState {
                seq: 62,
                total: 900,
                handed: Some(Handed { seq, total }),
                ..CounterState::default()
            },
        )])
    }

    /// Readings 61 and 62 (total 700 → 900) waited for a save that a crash followed: the
    /// first reading of the next run counts from 60 and carries their 200 pulses.
    #[test]
    fn after_a_crash_the_first_reading_counts_from_the_last_one_handed_over() {
        let mut channels = handed_at(60, 700);
        let resumed = resume(&mut channels, true);
        assert_eq!(
            (resumed["k"].after_seq, resumed["k"].carry),
            (Some(60), 200)
        );
        assert_eq!(channels["k"].seq, 62 + HEADROOM);
    }

    /// The publish policy held 50 pulses for its next reading at a clean stop: no
    /// `after_seq`, the first reading carries them.
    #[test]
    fn after_a_clean_stop_the_first_reading_carries_what_the_policy_held() {
        let mut channels = handed_at(62, 850);
        let resumed = resume(&mut channels, false);
        assert_eq!((resumed["k"].after_seq, resumed["k"].carry), (None, 50));
        assert_eq!(channels["k"].seq, 62, "no seq moved");
        let mut nothing_held = BTreeMap::from([("k".to_string(), CounterState::default())]);
        assert!(resume(&mut nothing_held, false).is_empty());
    }

    #[test]
    fn an_older_save_finishing_late_never_lowers_a_limit() {
        let mut l = Ledger::default();
        l.durable(&BTreeMap::from([("k".to_string(), 500)]));
        l.durable(&BTreeMap::from([("k".to_string(), 10)]));
        assert!(l.allows("k", 500 + HEADROOM));
    }
}

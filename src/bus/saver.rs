//! Saving a bus's state off the runtime thread, one save at a time (two saves never race on one
//! temp file), and telling the [`Ledger`] which seqs are durable once a save has completed.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;

use tokio::task::JoinHandle;

use super::ledger::{Ledger, seqs};
use crate::state::{BusState, StateError};

type Done = (BTreeMap<String, u64>, Result<(), StateError>);

/// The state saver of one bus.
pub struct Saver {
    path: PathBuf,
    bus: Arc<str>,
    running: Option<JoinHandle<Done>>,
    failing: bool,
}

impl Saver {
    pub fn new(path: PathBuf, bus: Arc<str>) -> Saver {
        Saver {
            path,
            bus,
            running: None,
            failing: false,
        }
    }

    fn spawn(&mut self, state: BusState) {
        let path = self.path.clone();
        self.running = Some(tokio::task::spawn_blocking(move || {
            let result = state.save(&path);
            (seqs(&state.channels), result)
        }));
    }

    fn finish(&mut self, done: Result<Done, tokio::task::JoinError>, ledger: &mut Ledger) -> bool {
        match done {
            Ok((seqs, Ok(()))) => {
                if std::mem::take(&mut self.failing) {
                    tracing::info!(bus = %self.bus, "state saved again");
                }
                ledger.durable(&seqs);
                true
            }
            Ok((_, Err(e))) => {
                if !std::mem::replace(&mut self.failing, true) {
                    tracing::error!(bus = %self.bus, "{e}; readings go on, but after a crash seq may repeat until a save succeeds");
                }
                false
            }
            Err(e) => {
                tracing::error!(bus = %self.bus, "state save task failed: {e}");
                false
            }
        }
    }

    /// Starts a periodic save unless one is still running (then this one is skipped).
    pub fn start(&mut self, state: BusState) {
        if self.running.is_none() {
            self.spawn(state);
        }
    }

    /// Collects a finished save without waiting.
    pub async fn collect(&mut self, ledger: &mut Ledger) {
        if self.running.as_ref().is_some_and(JoinHandle::is_finished) {
            self.wait(ledger).await;
        }
    }

    /// Waits for the running save, if any.
    pub async fn wait(&mut self, ledger: &mut Ledger) {
        if let Some(h) = self.running.take() {
            let done = h.await;
            self.finish(done, ledger);
        }
    }

    /// Saves `state` now (after the running save) and waits; whether it succeeded.
    pub async fn save_now(&mut self, state: BusState, ledger: &mut Ledger) -> bool {
        self.wait(ledger).await;
        self.spawn(state);
        let h = self.running.take().expect("just spawned");
        let done = h.await;
        self.finish(done, ledger)
    }
}

/// The way out of a bus for readings: a reading whose seq is not yet covered by a durable save
/// waits for one (see [`super::ledger`]); the first reading of each channel after a crash
/// carries `after_seq`.
pub struct Durable {
    pub saver: Saver,
    ledger: Ledger,
    /// Per channel key, the seq saved before a crash, until the channel's first reading.
    after_seq: BTreeMap<String, u64>,
}

impl Durable {
    pub fn new(saver: Saver, after_seq: BTreeMap<String, u64>) -> Durable {
        Durable {
            saver,
            ledger: Ledger::default(),
            after_seq,
        }
    }

    /// Collects a finished periodic save.
    pub async fn collect(&mut self) {
        self.saver.collect(&mut self.ledger).await;
    }

    /// Publishes `readings` of `devices`, saving first when a seq is beyond the durable one.
    pub async fn publish(
        &mut self,
        mut readings: Vec<crate::reading::Reading>,
        devices: &[super::DeviceRt],
        out: &tokio::sync::mpsc::UnboundedSender<crate::reading::Output>,
    ) {
        let key = |r: &crate::reading::Reading| {
            devices
                .iter()
                .find(|d| d.name == r.device)
                .map(|d| crate::state::channel_key(d.unit, &d.config.model, &r.channel))
        };
        let blocked = readings
            .iter()
            .any(|r| key(r).is_some_and(|k| !self.ledger.allows(&k, r.update.seq)));
        if blocked {
            // Publishing anyway when the save fails: readings matter more than seq after a
            // crash, and the failure is logged.
            self.saver
                .save_now(super::snapshot(devices, false), &mut self.ledger)
                .await;
        }
        for r in &mut readings {
            if let Some(k) = key(r) {
                r.after_seq = self.after_seq.remove(&k);
            }
        }
        for r in readings {
            let _ = out.send(crate::reading::Output::Reading(r));
        }
    }

    /// The last save, at shutdown: every reading is published, seq may go on from here.
    pub async fn finish(&mut self, devices: &[super::DeviceRt]) -> bool {
        self.saver
            .save_now(super::snapshot(devices, true), &mut self.ledger)
            .await
    }
}

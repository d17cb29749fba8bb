//! Saving a bus's state off the runtime thread, one save at a time (two saves never race on one
//! temp file), and telling the [`Ledger`] which seqs are durable once a save has completed.
//!
//! A save records the seq of every reading the bus has sent; after a crash the next run's
//! first readings count from it (`after_seq`). So a save is written only once the MQTT task has
//! said that everything sent before it is durable (acknowledged by the broker or fsynced in the
//! spool): the [`Checkpoint`] goes down the output first, and the file waits for its answer.

use std::collections::BTreeMap;
use std::path::PathBuf;
use std::sync::Arc;
use std::time::Duration;

use tokio::sync::oneshot;
use tokio::task::JoinHandle;
use tokio::time::Instant;

use super::ledger::{Ledger, seqs};
use crate::reading::{Checkpoint, Output};
use crate::state::{BusState, StateError};

type Done = (BTreeMap<String, u64>, Result<(), StateError>);

/// How long a save waits for the MQTT task's answer before it is given up (and retried).
const DURABLE_WAIT: Duration = Duration::from_secs(15);

/// A save under way.
enum Running {
    /// Waiting for the readings sent before it to be durable.
    Waiting {
        answer: oneshot::Receiver<bool>,
        state: Box<BusState>,
        since: Instant,
    },
    /// Writing the file.
    Saving(JoinHandle<Done>),
}

/// The state saver of one bus.
pub struct Saver {
    path: PathBuf,
    bus: Arc<str>,
    running: Option<Running>,
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

    fn spawn(&mut self, state: BusState) -> JoinHandle<Done> {
        let path = self.path.clone();
        tokio::task::spawn_blocking(move || {
            let result = state.save(&path);
            (seqs(&state.channels), result)
        })
    }

    /// Asks the MQTT task (through `out`) to make what was sent before durable.
    fn checkpoint(
        &mut self,
        state: BusState,
        out: &tokio::sync::mpsc::UnboundedSender<Output>,
    ) -> Running {
        let (checkpoint, answer) = Checkpoint::new();
        // Sent nowhere (no MQTT task): there is no one to lose readings to; the answer's
        // sender is dropped with the message, which the wait takes as a yes.
        let _ = out.send(Output::Checkpoint(checkpoint));
        Running::Waiting {
            answer,
            state: Box::new(state),
            since: Instant::now(),
        }
    }

    /// A save waiting for its answer: the file is written (yes, or no MQTT task), or the
    /// save fails (no, or no answer in time).
    fn answered(&mut self, durable: Option<bool>, state: BusState) -> Option<Done> {
        match durable {
            Some(true) | None => {
                self.running = Some(Running::Saving(self.spawn(state)));
                None
            }
            Some(false) => Some((BTreeMap::new(), Err(StateError::NotDurable))),
        }
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

    /// The last save failed.
    pub fn failing(&self) -> bool {
        self.failing
    }

    /// Starts a periodic save unless one is still running (then this one is skipped). The
    /// readings already sent on `out` are made durable first ([`Output::Checkpoint`]).
    pub fn start(&mut self, state: BusState, out: &tokio::sync::mpsc::UnboundedSender<Output>) {
        if self.running.is_none() {
            self.running = Some(self.checkpoint(state, out));
        }
    }

    /// Moves the running save on without waiting: writes it once its answer came, collects
    /// it once written.
    pub async fn collect(&mut self, ledger: &mut Ledger) {
        match self.running.take() {
            Some(Running::Waiting {
                mut answer,
                state,
                since,
            }) => {
                let durable = match answer.try_recv() {
                    Ok(yes) => Some(yes),
                    Err(oneshot::error::TryRecvError::Closed) => None,
                    Err(oneshot::error::TryRecvError::Empty) if since.elapsed() < DURABLE_WAIT => {
                        self.running = Some(Running::Waiting {
                            answer,
                            state,
                            since,
                        });
                        return;
                    }
                    Err(oneshot::error::TryRecvError::Empty) => Some(false),
                };
                if let Some(done) = self.answered(durable, *state) {
                    self.finish(Ok(done), ledger);
                }
            }
            Some(Running::Saving(h)) if h.is_finished() => {
                let done = h.await;
                self.finish(done, ledger);
            }
            other => self.running = other,
        }
    }

    /// Waits for the running save, if any (its answer first).
    pub async fn wait(&mut self, ledger: &mut Ledger) {
        let h = match self.running.take() {
            None => return,
            Some(Running::Saving(h)) => h,
            Some(Running::Waiting { answer, state, .. }) => {
                let durable = match tokio::time::timeout(DURABLE_WAIT, answer).await {
                    Ok(Ok(yes)) => Some(yes),
                    Ok(Err(_)) => None,
                    Err(_) => Some(false),
                };
                if let Some(done) = self.answered(durable, *state) {
                    self.finish(Ok(done), ledger);
                    return;
                }
                match self.running.take() {
                    Some(Running::Saving(h)) => h,
                    _ => return,
                }
            }
        };
        let done = h.await;
        self.finish(done, ledger);
    }

    /// Saves `state` now (after the running save) and waits; whether it succeeded.
    pub async fn save_now(
        &mut self,
        state: BusState,
        ledger: &mut Ledger,
        out: &tokio::sync::mpsc::UnboundedSender<Output>,
    ) -> bool {
        self.wait(ledger).await;
        self.running = Some(self.checkpoint(state, out));
        self.wait(ledger).await;
        !self.failing
    }
}

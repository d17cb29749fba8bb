//! State saves' checkpoints: answered when everything before them is acknowledged by the
//! broker, or (broker away or slow) fsynced in the spool.

use std::time::Duration;

use tokio::time::Instant;

use super::{CHECKPOINT_WAIT, PendingCheckpoint, Publisher};
use crate::reading::Checkpoint;

impl Publisher<'_> {
    /// A state save asks whether everything before it is durable: held readings go to the
    /// broker now; the answer comes when the broker has acknowledged them, or (broker away or
    /// slow) once they are fsynced in the spool.
    pub(super) fn checkpoint(&mut self, checkpoint: Checkpoint) {
        self.pump();
        let upto = self.shell.outbox.next_seq().saturating_sub(1);
        self.checkpoints.push(PendingCheckpoint {
            checkpoint,
            upto,
            since: Instant::now(),
        });
        self.settle(Instant::now());
    }
    /// Answers the checkpoints the broker has settled by acknowledging; those it left too long
    /// (or every one, while it is away) are made durable on disk.
    pub(super) fn settle(&mut self, now: Instant) {
        if self.checkpoints.is_empty() {
            return;
        }
        let oldest = self.shell.outbox.oldest_unacked();
        let up = self.shell.outbox.is_connected();
        let (done, waiting): (Vec<_>, Vec<_>) = std::mem::take(&mut self.checkpoints)
            .into_iter()
            .partition(|p| oldest.is_none_or(|o| o > p.upto));
        for p in done {
            p.checkpoint.answer(true);
        }
        let (to_disk, waiting): (Vec<_>, Vec<_>) = waiting
            .into_iter()
            .partition(|p| !up || now.saturating_duration_since(p.since) >= CHECKPOINT_WAIT);
        self.checkpoints = waiting;
        if !to_disk.is_empty() {
            self.sync_to_disk(to_disk);
        }
    }
    /// Spills what only memory holds and answers `checkpoints` once the disk has it: `false`
    /// when something could not be written or synced (the save then waits for the broker).
    pub(super) fn sync_to_disk(&mut self, checkpoints: Vec<PendingCheckpoint>) {
        let durable = self.shell.outbox.store_mut().durable();
        tokio::task::spawn_blocking(move || {
            let durable = durable.wait(Duration::from_secs(5));
            for p in checkpoints {
                p.checkpoint.answer(durable);
            }
        });
    }
}

//! Bus output to every output: each event is handed to each output's own unbounded channel, so
//! a slow, held or disconnected output backs up only itself (vector's topology, Telegraf's
//! outputs). What the gateway does once per event, whatever the outputs, is done here: device
//! availability for health, command answers for the metrics, every event for the status
//! board (when the status page is served).
//!
//! A state save's [`Checkpoint`] asks every output: the save may record a seq only once each of
//! them has what came before it acknowledged or fsynced, so the checkpoint is split in one per
//! output and answered when all have answered (`false` when any could not make it durable).

use std::sync::Arc;

use tokio::sync::mpsc::{UnboundedReceiver, UnboundedSender};

use crate::health::Health;
use crate::metrics::Metrics;
use crate::reading::{Checkpoint, Output};

/// Where events go, and what is told once about them.
pub struct Fanout {
    pub outputs: Vec<UnboundedSender<Output>>,
    pub health: Arc<Health>,
    pub metrics: Metrics,
    /// The status page's board, when the HTTP endpoint serves it.
    pub status: Option<Arc<crate::status::Live>>,
}

impl Fanout {
    /// Until every sender of `events` (the buses, the router) is gone; then the outputs'
    /// channels close too. `answers` (what the outputs answer themselves) does not keep it
    /// running: the outputs hold its senders until they end, which they do when it ends.
    /// `swaps` hands it the channels of a new set of outputs (a pushed config rebuilt them):
    /// the old ones are dropped, so their tasks end, and every event from then on goes to the
    /// new ones (which keep it until they run).
    pub async fn run(
        mut self,
        mut events: UnboundedReceiver<Output>,
        mut answers: UnboundedReceiver<Output>,
        mut swaps: UnboundedReceiver<Vec<UnboundedSender<Output>>>,
    ) {
        loop {
            tokio::select! {
                event = events.recv() => match event {
                    Some(event) => self.hand(event),
                    None => return,
                },
                Some(answer) = answers.recv() => self.hand(answer),
                Some(outputs) = swaps.recv() => self.outputs = outputs,
            }
        }
    }

    /// One event to every output.
    pub fn hand(&self, event: Output) {
        match &event {
            Output::DeviceStatus { device, online } => self.health.device(device, *online),
            Output::DeviceProblem { device, .. } => self.health.device(device, false),
            Output::CommandResult { outcome, .. } => self.metrics.command_result(outcome),
            Output::Checkpoint(c) => return self.checkpoint(c),
            _ => {}
        }
        if let Some(board) = &self.status {
            board.hand(&event);
        }
        if let Some((last, rest)) = self.outputs.split_last() {
            for out in rest {
                let _ = out.send(event.clone());
            }
            let _ = last.send(event);
        }
    }

    /// One checkpoint per output, joined.
    fn checkpoint(&self, checkpoint: &Checkpoint) {
        let mut answers = Vec::with_capacity(self.outputs.len());
        for out in &self.outputs {
            let (child, answer) = Checkpoint::new();
            if out.send(Output::Checkpoint(child)).is_ok() {
                answers.push(answer);
            }
        }
        let checkpoint = checkpoint.clone();
        tokio::spawn(async move {
            let mut durable = true;
            for answer in answers {
                // An output that ended without answering has no one to lose readings to.
                durable &= answer.await.unwrap_or(true);
            }
            checkpoint.answer(durable);
        });
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use tokio::sync::mpsc::unbounded_channel;

    fn fanout(n: usize) -> (Fanout, Vec<UnboundedReceiver<Output>>) {
        let (senders, receivers) = (0..n).map(|_| unbounded_channel()).unzip();
        let f = Fanout {
            outputs: senders,
            health: Arc::default(),
            metrics: Metrics::disabled(),
            status: None,
        };
        (f, receivers)
    }

    fn checkpoint_of(rx: &mut UnboundedReceiver<Output>) -> Checkpoint {
        match rx.try_recv() {
            Ok(Output::Checkpoint(c)) => c,
            other => panic!("expected a checkpoint, got {other:?}"),
        }
    }

    #[tokio::test]
    async fn every_output_gets_every_reading() {
        let (f, mut rx) = fanout(2);
        f.hand(Output::single(crate::reading::Reading::sample(
            "d", "enc0", 1,
        )));
        for r in &mut rx {
            assert!(matches!(r.try_recv(), Ok(Output::DeviceReadings { .. })));
        }
    }

    #[tokio::test]
    async fn a_save_is_durable_only_when_every_output_says_so() {
        let (f, mut rx) = fanout(2);
        let (c, answer) = Checkpoint::new();
        f.hand(Output::Checkpoint(c));
        let (a, b) = (checkpoint_of(&mut rx[0]), checkpoint_of(&mut rx[1]));
        a.answer(true);
        tokio::task::yield_now().await;
        b.answer(false);
        assert!(
            !answer.await.unwrap(),
            "one output could not make it durable"
        );
    }

    #[tokio::test]
    async fn a_save_waits_for_the_slowest_output() {
        let (f, mut rx) = fanout(2);
        let (c, mut answer) = Checkpoint::new();
        f.hand(Output::Checkpoint(c));
        let (a, b) = (checkpoint_of(&mut rx[0]), checkpoint_of(&mut rx[1]));
        a.answer(true);
        for _ in 0..10 {
            tokio::task::yield_now().await;
        }
        assert!(
            answer.try_recv().is_err(),
            "the second output has not answered"
        );
        b.answer(true);
        assert!(answer.await.unwrap());
    }

    #[tokio::test]
    async fn an_output_that_is_gone_costs_the_save_nothing() {
        let (f, mut rx) = fanout(2);
        drop(rx.pop());
        let (c, answer) = Checkpoint::new();
        f.hand(Output::Checkpoint(c));
        checkpoint_of(&mut rx[0]).answer(true);
        assert!(answer.await.unwrap());
    }
}

//! The router's shell: it owns the channels the router's actions go to (each bus's command
//! and scan queues, the remote config task, the fan-out), carries the actions out, and brings
//! back as events into the same loop what the router must hear: a bus's answer, a queue that
//! did not take a survey or a push, a reloaded config.

use std::collections::{HashMap, VecDeque};

use tokio::sync::mpsc::error::TrySendError;
use tokio::sync::mpsc::{Receiver, Sender, UnboundedReceiver, UnboundedSender};
use tokio::sync::oneshot;
use tokio::task::JoinSet;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::router::{Action, Event, Incoming, Pending, Router, ScanRefusal, Target};
use crate::bus::BusCommand;
use crate::command::CommandError;
use crate::reading::Output;
use crate::scan::ScanRequest;

/// Where the router's actions go after a (re)start of the buses: each running bus's command
/// and scan queues, and its devices.
pub struct Wiring {
    pub buses: HashMap<String, UnboundedSender<BusCommand>>,
    pub scans: HashMap<String, Sender<ScanRequest>>,
    pub targets: HashMap<String, Target>,
}

/// The channels the actions go out on.
struct Lines {
    buses: HashMap<String, UnboundedSender<BusCommand>>,
    scans: HashMap<String, Sender<ScanRequest>>,
    remote: Option<Sender<Incoming>>,
    out: UnboundedSender<Output>,
    /// Commands a bus has, until it answers.
    waiting: JoinSet<(Pending, Result<Option<i64>, CommandError>)>,
}

impl Lines {
    /// Carries `action` out; what the router must hear of it comes back.
    fn carry(&mut self, action: Action) -> Option<Event> {
        match action {
            Action::Publish(output) => {
                let _ = self.out.send(output);
                None
            }
            Action::Forward(bus, request, pending) => self.forward(&bus, *request, pending),
            Action::Scan(bus, request) => {
                let (request, refusal) = match self.scans.get(&bus) {
                    None => (request, ScanRefusal::UnknownBus),
                    Some(tx) => match tx.try_send(request) {
                        Ok(()) => return None,
                        Err(TrySendError::Full(r) | TrySendError::Closed(r)) => {
                            (r, ScanRefusal::Busy)
                        }
                    },
                };
                Some(Event::ScanNotTaken {
                    bus,
                    reply: request.reply,
                    refusal,
                })
            }
            Action::Push(msg) => match self.remote.as_ref()?.try_send(msg) {
                Ok(()) => None,
                Err(TrySendError::Full(msg)) => Some(Event::PushNotTaken { msg, closed: false }),
                Err(TrySendError::Closed(msg)) => Some(Event::PushNotTaken { msg, closed: true }),
            },
        }
    }

    /// Hands a command to bus `bus`; a bus that does not take it leaves it `offline`.
    fn forward(
        &mut self,
        bus: &str,
        request: crate::command::Request,
        pending: Pending,
    ) -> Option<Event> {
        let offline = || CommandError::Offline(pending.device.clone());
        let Some(tx) = self.buses.get(bus) else {
            return Some(Event::Answered(pending.clone(), Err(offline())));
        };
        let (done, answer) = oneshot::channel();
        if tx.send(BusCommand { request, done }).is_err() {
            return Some(Event::Answered(pending.clone(), Err(offline())));
        }
        self.waiting.spawn(async move {
            let result = answer
                .await
                .unwrap_or_else(|_| Err(CommandError::Offline("gateway stopping".into())));
            (pending, result)
        });
        None
    }
}

/// Runs `router` on the messages of `incoming` and the bus answers, taking each new
/// [`Wiring`] (a reload) before anything else, until `incoming` closes or `stop` is
/// cancelled; then answers what the buses still had (they stopped first) and ends.
pub async fn run(
    mut router: Router,
    wiring: Wiring,
    mut incoming: Receiver<Incoming>,
    mut rewired: UnboundedReceiver<Wiring>,
    remote: Option<Sender<Incoming>>,
    out: UnboundedSender<Output>,
    stop: CancellationToken,
) {
    let mut lines = Lines {
        buses: wiring.buses,
        scans: wiring.scans,
        remote,
        out,
        waiting: JoinSet::new(),
    };
    loop {
        let event = tokio::select! {
            biased;
            Some(w) = rewired.recv() => {
                (lines.buses, lines.scans) = (w.buses, w.scans);
                Event::Reconfigured(w.targets)
            }
            Some(Ok((pending, result))) = lines.waiting.join_next(), if !lines.waiting.is_empty() => {
                Event::Answered(pending, result)
            }
            () = stop.cancelled() => break,
            msg = incoming.recv() => match msg {
                Some(msg) => Event::Message(msg),
                None => break,
            },
        };
        step(&mut router, &mut lines, event);
    }
    lines.buses.clear();
    while let Some(joined) = lines.waiting.join_next().await {
        if let Ok((pending, result)) = joined {
            step(&mut router, &mut lines, Event::Answered(pending, result));
        }
    }
}

/// One event through the router, and whatever its actions bring back, in order.
fn step(router: &mut Router, lines: &mut Lines, event: Event) {
    let mut queue = VecDeque::from([event]);
    while let Some(event) = queue.pop_front() {
        for action in router.handle(event, Instant::now()) {
            queue.extend(lines.carry(action));
        }
    }
}

//! The connection side of the MQTT task: one task per connection polls rumqttc's event loop and
//! moves what it reports to the MQTT task ([`super::mqtt`]) over a bounded channel. It owns
//! nothing of the shell (outbox, client): the MQTT task alone does, so nothing is shared.
//!
//! Why a task of its own: rumqttc does not promise that `EventLoop::poll` is cancel-safe, and it
//! is not (cut off while feeding a packet to the socket, it drops a packet its state already
//! counts in flight), so it is never raced against the bus output or the timers, only dropped
//! with the connection it drives; and a publish must never be awaited where the event loop is
//! polled (that can deadlock rumqttc). Commands go straight to the router, waiting when it is behind
//! (the connection then stops reading and TCP pushes back on the sender).

use std::time::Duration;

use tokio::sync::mpsc::{Receiver, Sender, channel};
use tokio::task::JoinHandle;

use super::session::{Event, EventLoop, Failure, Received};
use crate::dispatch::Incoming;

/// What a connection reports to the MQTT task: an event, or how it ended.
pub type Polled = Result<Event, Failure>;

/// Reports waiting for the MQTT task; when full, the connection waits (TCP pushes back).
const QUEUE: usize = 64;

/// Where received messages go.
#[derive(Clone)]
pub struct Routes {
    /// Topic filters whose messages go to the MQTT task (the boot marker, the formats'
    /// subscriptions); everything else goes to the router.
    pub to_task: Vec<String>,
    /// The command router.
    pub router: Sender<Incoming>,
    /// This connection, named on each command so its answer is said here.
    pub via: crate::command::Via,
}

impl Routes {
    fn to_task(&self, topic: &[u8]) -> bool {
        let Ok(topic) = std::str::from_utf8(topic) else {
            return false;
        };
        self.to_task.iter().any(|f| rumqttc::matches(topic, f))
    }
}

/// One connection being polled, and its reports. Dropping it drops the connection and the
/// reports not yet taken (a late acknowledgement of a connection given up must not release a
/// message the outbox already counts as unsent).
pub struct Poller {
    pub events: Receiver<Polled>,
    task: JoinHandle<()>,
}

impl Poller {
    /// Polls `eventloop` after `pause` (the back-off after a failure).
    pub fn start(eventloop: EventLoop, pause: Duration, routes: Routes) -> Poller {
        let (tx, events) = channel(QUEUE);
        let task = tokio::spawn(poll(eventloop, pause, routes, tx));
        Poller { events, task }
    }

    /// Lets the connection write what it was given (the gateway's offline status, our
    /// DISCONNECT) for up to `grace`, then drops it. Reports are no longer taken.
    pub async fn finish(&mut self, grace: Duration) {
        self.events.close();
        let _ = tokio::time::timeout(grace, &mut self.task).await;
    }

    /// A poller whose connection never reports by itself, and the sender of its reports.
    #[cfg(test)]
    pub fn scripted() -> (Poller, Sender<Polled>) {
        let (tx, events) = channel(QUEUE);
        let task = tokio::spawn(std::future::pending());
        (Poller { events, task }, tx)
    }
}

impl Drop for Poller {
    fn drop(&mut self) {
        self.task.abort();
    }
}

/// Polls until the connection ends (a failure, our DISCONNECT, the client dropped), reporting
/// to the MQTT task; once that no longer listens (it is finishing), polls on so what it queued
/// is still written.
async fn poll(mut eventloop: EventLoop, pause: Duration, routes: Routes, events: Sender<Polled>) {
    tokio::time::sleep(pause).await;
    loop {
        let polled = eventloop.poll().await;
        match polled {
            Ok(Event::Other) => continue,
            Ok(Event::Received(p)) if !routes.to_task(&p.topic) => {
                command(p, &routes.router, &routes.via).await;
                continue;
            }
            _ => {}
        }
        let last = matches!(polled, Ok(Event::Disconnected) | Err(_));
        let _ = events.send(polled).await;
        if last {
            return;
        }
    }
}

/// A message on a command topic (or any filter not the MQTT task's) to the router.
async fn command(p: Received, router: &Sender<Incoming>, via: &crate::command::Via) {
    let msg = Incoming {
        topic: String::from_utf8_lossy(&p.topic).into_owned(),
        payload: p.payload,
        retain: p.retain,
        response_topic: p.response_topic,
        correlation: p.correlation,
        via: Some(via.clone()),
    };
    if router.send(msg).await.is_err() {
        tracing::debug!("command router gone");
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn the_boot_marker_and_format_subscriptions_go_to_the_task_and_the_rest_to_the_router() {
        let (router, _rx) = channel(1);
        let routes = Routes {
            to_task: vec!["pg/t/gateway".into(), "homeassistant/+/t/+/config".into()],
            router,
            via: crate::command::Via {
                output: "json".into(),
                wrote: None,
            },
        };
        assert!(routes.to_task(b"pg/t/gateway"));
        assert!(routes.to_task(b"homeassistant/sensor/t/x/config"));
        assert!(!routes.to_task(b"pg/t/press1/cmd"));
        assert!(!routes.to_task(b"homeassistant/sensor/other/x/config"));
        assert!(
            !routes.to_task(&[0xff, 0xfe]),
            "not UTF-8: the router says why"
        );
    }
}

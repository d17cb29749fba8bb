//! What arrives on the output's subscriptions: the boot marker, the formats' messages and the
//! commands of their protocols (into the router's bounded queue, or answered `busy`), and what
//! their protocols ask of the output or the gateway.

use super::Publisher;
use crate::dispatch::Incoming;
use crate::publish::lifecycle::Control;
use crate::reading::Output;

impl Publisher<'_> {
    /// A message on the boot marker or a format's subscription (the poller sends the rest to
    /// the router); commands a format makes of it go to the router too, never waiting on it.
    pub(super) fn received(&mut self, topic: &[u8], payload: &[u8], retained: bool) {
        let topic = String::from_utf8_lossy(topic);
        if topic == self.shell.topics.gateway_marker() {
            self.watch.marker(payload, &self.link);
            return;
        }
        let reaction = if retained {
            self.stage.received_retained(&topic, payload)
        } else {
            self.stage.received(&topic, payload)
        };
        for m in reaction.at_once {
            self.shell.publish_direct(m);
        }
        for m in reaction.messages {
            self.shell.queue(m);
        }
        for c in reaction.commands {
            self.admit(c);
        }
        for a in reaction.answers {
            let _ = self.task.answers.send(a);
        }
        for c in reaction.control {
            self.control(c);
        }
        self.pump();
    }
    /// What a format's protocol asked: the next broker now, or a reboot of the gateway.
    pub(super) fn control(&mut self, c: Control) {
        match c {
            Control::NextServer => self.move_on("its protocol asked for the next server"),
            Control::Reboot => {
                let _ = self.task.controls.send(Control::Reboot);
            }
        }
    }
    /// A command of a format's own protocol into the router's bounded queue; when the queue is
    /// full it is refused (answered `busy`, counted), never dropped.
    pub(super) fn admit(&mut self, c: Incoming) {
        let Err(e) = self.routes.router.try_send(c) else {
            return;
        };
        let c = e.into_inner();
        let busy = crate::command::CommandError::Busy {
            device: c
                .via
                .as_ref()
                .and_then(|v| v.wrote.as_ref())
                .map_or_else(String::new, |w| w.device.clone()),
            why: "the gateway's command queue is full",
        };
        let outcome = crate::outcome::Outcome::Command(crate::outcome::CommandOutcome {
            id: None,
            op: None,
            result: Err(busy),
        });
        let reply = crate::command::Reply {
            topics: Vec::new(),
            correlation: None,
            via: c.via,
        };
        let _ = self
            .task
            .answers
            .send(Output::CommandResult { reply, outcome });
    }
}

//! The gateway's own voice, which belongs to no format: its status (`online` at every
//! connection, `offline` when it stops, and `offline` as the will), the answers to the
//! commands and scans that came in on this connection's command topics, and a scan's progress.
//! Every connection that carries the gateway's JSON topics has it, and so does the gateway's
//! own connection when no output carries them on the `[mqtt]` broker
//! (`config::outputs::VoiceHome`). Pure.

use bytes::Bytes;

use super::format::Format;
use super::lifecycle::Lifecycle;
use crate::outbox::{Content, Message, Will};
use crate::reading::Output;
use crate::topics::Topics;

/// The voice on one connection.
#[derive(Debug, Clone)]
pub struct Voice {
    topics: Topics,
    root: String,
    /// The connection's name (its output's, or the gateway's own): answers to what came in
    /// on it are said here.
    connection: String,
}

impl Voice {
    pub fn new(topic_root: &str, connection: &str) -> Voice {
        Voice {
            topics: Topics::new(topic_root),
            root: topic_root.to_string(),
            connection: connection.to_string(),
        }
    }

    fn is_ours(&self, reply: &crate::command::Reply) -> bool {
        match &reply.via {
            Some(via) => *via.output == *self.connection,
            None => reply.topics.first().is_some_and(|t| self.under_root(t)),
        }
    }

    fn under_root(&self, topic: &str) -> bool {
        topic
            .strip_prefix(&self.root)
            .is_some_and(|rest| rest.starts_with('/'))
    }

    fn status(&self, word: &'static str) -> Message {
        Message::new(self.topics.gateway_status(), word, 1, true)
    }
}

impl Format for Voice {
    /// Results of what came in on this connection, to the topics they name (none for a command
    /// of an output's own protocol: that output answers it); progress under this root.
    fn messages(&mut self, event: &Output) -> Vec<Message> {
        match event {
            Output::CommandResult { reply, outcome } if self.is_ours(reply) => {
                let body = Bytes::from(outcome.to_json().to_string());
                let mut out = Vec::with_capacity(reply.topics.len());
                for (i, topic) in reply.topics.iter().enumerate() {
                    let mut m = Message::new(topic.clone(), body.clone(), 1, false)
                        .carrying(Content::Answer);
                    // The MQTT v5 response topic (after the result topic) gets the request's
                    // correlation data back.
                    if i > 0 {
                        m.properties.correlation = reply.correlation.clone();
                    }
                    out.push(m);
                }
                out
            }
            Output::ScanProgress { topic, progress } if self.under_root(topic) => {
                let body = serde_json::to_string(&**progress).unwrap_or_default();
                vec![Message::new(topic.clone(), body, 1, false).carrying(Content::Answer)]
            }
            _ => Vec::new(),
        }
    }
}

impl Lifecycle for Voice {
    /// The gateway's status, retained: `online` at every connection.
    fn connected(&mut self) -> Vec<Message> {
        vec![self.status("online")]
    }

    /// `offline` when the connection dies without a word.
    fn will(&mut self) -> Option<Will> {
        Some(Will {
            topic: self.topics.gateway_status(),
            payload: Bytes::from_static(b"offline"),
            qos: 1,
            retain: true,
        })
    }

    /// `offline` as the gateway stops.
    fn stopping(&mut self) -> Vec<Message> {
        vec![self.status("offline")]
    }
}

//! The grace period of an applied push, and what the state directory keeps of it: the watch
//! is written there before the push is applied, so a crash, a `kill -9` or a power cut inside
//! the grace never strands a pushed config. At the next start [`resume`] decides from the hash
//! of the config that runs what happened and what is left to do.

use std::collections::BTreeSet;
use std::path::PathBuf;

use tokio::time::Instant;

use crate::config::Config;

/// The grace period of an applied push: what must hold at its end for the config to stay.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Watch {
    pub id: Option<String>,
    pub until: Instant,
    /// The connection that delivered it (its health loop is `output/<name>`).
    pub connection: String,
    /// Devices that were online before and are still configured, not yet heard again.
    pub waiting: BTreeSet<String>,
}

impl Watch {
    /// A watch of `grace` from `now` for the devices `online_before` that `new` still polls.
    pub fn new(
        id: Option<String>,
        now: Instant,
        grace: std::time::Duration,
        connection: &str,
        online_before: &[String],
        new: &Config,
    ) -> Watch {
        let configured: BTreeSet<String> =
            new.enabled_devices().map(|(_, d)| d.name.clone()).collect();
        Watch {
            id,
            until: now + grace,
            connection: connection.to_string(),
            waiting: online_before
                .iter()
                .filter(|d| configured.contains(*d))
                .cloned()
                .collect(),
        }
    }

    /// Devices online now: each one waited for has answered again.
    pub fn online(&mut self, devices: &[String]) {
        for d in devices {
            self.waiting.remove(d);
        }
    }

    /// At the end of the grace period, whether the config stays: `Ok`, or why it goes.
    /// `None` before the end.
    pub fn verdict(&self, now: Instant, connection_up: bool) -> Option<Result<(), String>> {
        if now < self.until {
            return None;
        }
        if !connection_up {
            return Some(Err(format!(
                "the connection that delivered it ({}) is not up",
                self.connection
            )));
        }
        if !self.waiting.is_empty() {
            let names: Vec<&str> = self.waiting.iter().map(String::as_str).collect();
            return Some(Err(format!(
                "devices online before did not answer again: {}",
                names.join(", ")
            )));
        }
        Some(Ok(()))
    }
}

/// What the state directory keeps of a push until its final result (`remote-watch.json`).
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize, serde::Deserialize)]
pub struct Record {
    pub id: Option<String>,
    /// The connection that delivered it.
    pub connection: String,
    /// The devices waited for (online before the push and still configured).
    pub waiting: Vec<String>,
    /// The file holding the config in force before the push.
    pub previous: PathBuf,
    /// The hash of the pushed config.
    pub pushed_hash: String,
    /// The hash of the config in force before (none when the file in force did not load).
    pub previous_hash: Option<String>,
    /// The push started the process again: the new one says `applied` with its hash.
    pub announce: bool,
    /// Decided: rolled back, for this reason (a restart may be needed to finish it).
    pub rollback: Option<String>,
}

/// What a start finds to do about a [`Record`] left in the state directory.
#[derive(Debug, Clone, PartialEq, Eq)]
pub enum Resume {
    /// The pushed config runs and is not decided: watch it for a whole grace period from now
    /// (the new start has its chance to connect); say `applied` first when `announce`.
    Watch { announce: bool },
    /// The pushed config runs and was to be rolled back: do it.
    RollBack(String),
    /// The previous config runs after a rollback: say `rolled_back`.
    RolledBack(String),
    /// The previous config runs and the push never was in force (the gateway stopped between
    /// keeping the watch and writing the file): say so.
    NeverApplied,
    /// Another config runs (the file was changed on site): the watch is dropped with a
    /// warning and rolls nothing back.
    Stale,
}

/// What to do about `record` when the config that runs has `running` as its hash.
pub fn resume(record: &Record, running: &str) -> Resume {
    let previous = record.previous_hash.as_deref() == Some(running);
    if record.pushed_hash == running && !previous {
        return match &record.rollback {
            Some(why) => Resume::RollBack(why.clone()),
            None => Resume::Watch {
                announce: record.announce,
            },
        };
    }
    match (&record.rollback, previous) {
        (Some(why), true) => Resume::RolledBack(why.clone()),
        (None, true) => Resume::NeverApplied,
        _ => Resume::Stale,
    }
}

impl Watch {
    /// The record of this watch.
    pub fn record(&self, previous: PathBuf, hashes: (String, Option<String>)) -> Record {
        Record {
            id: self.id.clone(),
            connection: self.connection.clone(),
            waiting: self.waiting.iter().cloned().collect(),
            previous,
            pushed_hash: hashes.0,
            previous_hash: hashes.1,
            announce: false,
            rollback: None,
        }
    }

    /// A watch resumed from its record, for `grace` from `now`.
    pub fn resumed(record: &Record, now: Instant, grace: std::time::Duration) -> Watch {
        Watch {
            id: record.id.clone(),
            until: now + grace,
            connection: record.connection.clone(),
            waiting: record.waiting.iter().cloned().collect(),
        }
    }
}

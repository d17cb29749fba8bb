//! Configs pushed from the broker (`[remote] config = true`), in the running gateway. A push is
//! read, its signature checked against `[remote] trusted_keys` (and its serial against the last
//! one taken), checked as `pulsegate check` checks a file, and refused with every reason when
//! it changes what its signature (or the lack of one) does not allow. Then its watch is kept in
//! the state directory, the file written (keeping its mode and owner; the previous kept as
//! `<file>.previous`), and the config applied: buses reloaded, outputs rebuilt, or the process
//! started again for what only a new start applies. For `[remote] grace` it is watched: if the
//! connection that delivered it is not up at its end, or a device that answered before has not
//! answered again, the previous file comes back and is applied the same way (starting again
//! when the push had). Each step is said on `<root>/config/result`, and every push gets one
//! final result (`kept`, `rolled_back` or `refused`), across restarts and crashes.

use tokio::time::Instant;

use super::{Gateway, Next};
use crate::config::Config;
use crate::dispatch::Incoming;
use crate::outcome::{ConfigOutcome, Outcome};
use crate::remote::guard::Signed;
use crate::remote::{Reach, Record, Refusal, Resume, Watch};

#[path = "pushed_files.rs"]
mod files;

/// A push in force and being watched, and what the state directory keeps of it.
pub(super) struct Pending {
    watch: Watch,
    record: Record,
}

impl Gateway {
    /// What a push left in the state directory: its watch goes on for a whole grace period
    /// from this start, a rollback decided before a restart is finished or said, and a watch
    /// of another config is dropped.
    pub(super) async fn resume_watch(&mut self, pending: &mut Option<Pending>) -> Next {
        let Some(record) = files::load_record(&self.current) else {
            return Next::Run;
        };
        let running = self.current.hash().to_string();
        match crate::remote::watch::resume(&record, &running) {
            Resume::Watch { announce } => {
                let grace = self.current.remote.grace;
                tracing::info!(id = ?record.id, "a pushed config is in force after a start: watched for {} s", grace.as_secs());
                if announce {
                    let message = format!(
                        "in force after the restart; watched for {} s",
                        grace.as_secs()
                    );
                    self.answer(&record.id, "applied", None, message);
                }
                let watch = Watch::resumed(&record, Instant::now(), grace);
                let record = Record {
                    announce: false,
                    ..record
                };
                self.keep_record(&record);
                *pending = Some(Pending { watch, record });
                Next::Run
            }
            Resume::RollBack(why) => self.roll_back(record, &why).await,
            Resume::RolledBack(why) => {
                let message = format!("rolled back to the previous config: {why}");
                self.finish(&record.id, "rolled_back", Some("rolled_back"), message);
                Next::Run
            }
            Resume::NeverApplied => {
                let message = "the gateway stopped before the pushed config was in force: the previous config runs; push again".to_string();
                self.finish(&record.id, "refused", Some("interrupted"), message);
                Next::Run
            }
            Resume::Stale => {
                tracing::warn!(id = ?record.id, "a pushed config's watch is dropped: the config in force is neither the pushed one nor the one before it (changed on site); nothing is rolled back");
                files::remove_record(&self.current);
                Next::Run
            }
        }
    }

    /// A pushed config: refused, or written, applied and watched.
    pub(super) async fn push(&mut self, msg: Incoming, pending: &mut Option<Pending>) -> Next {
        if msg.retain && msg.payload.is_empty() {
            tracing::info!("the retained message on the config topic was cleared");
            return Next::Run;
        }
        let connection = msg.via.as_ref().map_or_else(
            || crate::config::outputs::VOICE_NAME.to_string(),
            |v| v.output.to_string(),
        );
        let (push, new) = match self.admit(&msg, pending.as_ref()) {
            Ok(admitted) => admitted,
            Err((id, refusal)) => return self.refuse(id, &refusal),
        };
        let online = self.health.online_devices();
        let grace = new.remote.grace;
        let watch = Watch::new(push.id, Instant::now(), grace, &connection, &online, &new);
        let previous = files::previous_path(&self.current.source);
        let hashes = (new.hash().to_string(), files::hash_of_file(&self.current));
        let mut record = watch.record(previous, hashes);
        let restart = crate::remote::reach(&self.current, &new) == Reach::Restart;
        record.announce = restart;
        if let Err(e) = files::save_record(&self.current, &record)
            .and_then(|()| files::replace_config(&self.current.source, &push.toml))
        {
            files::remove_record(&self.current);
            let refusal = Refusal::WriteFailed(e.to_string());
            return self.refuse(watch.id.clone(), &refusal);
        }
        tracing::info!(id = ?watch.id, "a pushed config is in force: watched for {} s", grace.as_secs());
        if restart {
            let message =
                "written; the gateway starts again to apply it, and says when it is in force"
                    .into();
            self.answer(&watch.id, "applied", None, message);
            return Next::Restart;
        }
        self.take(new).await;
        let message = format!("in force; watched for {} s", grace.as_secs());
        self.answer(&watch.id, "applied", None, message);
        *pending = Some(Pending { watch, record });
        Next::Run
    }

    /// A push read, signed as this gateway asks, checked and allowed: the new config; or the
    /// push's id (when it could be read) and why not.
    fn admit(
        &self,
        msg: &Incoming,
        pending: Option<&Pending>,
    ) -> Result<(crate::remote::Push, Config), (Option<String>, Refusal)> {
        if msg.retain {
            let id = crate::remote::parse(&msg.payload).ok().and_then(|p| p.id);
            return Err((id, Refusal::Retained));
        }
        let push = crate::remote::parse(&msg.payload)?;
        let id = push.id.clone();
        if let Some(p) = pending {
            return Err((id, Refusal::Busy(p.watch.id.clone().unwrap_or_default())));
        }
        let signed = self.verify(&push).map_err(|r| (id.clone(), r))?;
        let new = self.check(&push.toml, signed).map_err(|r| (id, r))?;
        Ok((push, new))
    }

    /// Whether the push is signed as `[remote] trusted_keys` asks; a good signature's serial is
    /// taken (kept in the state directory) before anything else, so it can never be used again.
    fn verify(&self, push: &crate::remote::Push) -> Result<Signed, Refusal> {
        use crate::remote::signature;
        let keys = &self.current.remote.trusted_keys;
        let sig = match (&push.signed, keys.is_empty()) {
            (None, true) => return Ok(Signed::No),
            (Some(_), true) => return Err(Refusal::NoTrustedKeys),
            (None, false) => return Err(Refusal::Unsigned),
            (Some(sig), false) => sig,
        };
        let id = push.id.as_deref().unwrap_or_default();
        let gateway = &self.current.gateway.id;
        let bytes = signature::signed_bytes(gateway, id, sig.serial, &push.toml);
        signature::verify(keys, &bytes, &sig.value).map_err(Refusal::BadSignature)?;
        let last = files::last_serial(&self.current).map_err(Refusal::WriteFailed)?;
        crate::remote::admit_serial(last, sig.serial)?;
        files::take_serial(&self.current, sig.serial)
            .map_err(|e| Refusal::WriteFailed(format!("the serial: {e}")))?;
        Ok(Signed::Yes)
    }

    /// The pushed text, checked as a file in the config's place would be, and what it may
    /// change ([`crate::remote::guard`]).
    fn check(&self, toml: &str, signed: Signed) -> Result<Config, Refusal> {
        let new = Config::from_toml(toml, &self.current.source, None)
            .map_err(|e| Refusal::BadConfig(e.to_string().trim_end().to_string()))?;
        let forbidden = crate::remote::guard::forbidden_changes(&self.current, &new, signed);
        if !forbidden.is_empty() {
            return Err(Refusal::Forbidden(forbidden.join("; ")));
        }
        Ok(new)
    }

    /// Every second of a watch: who answered; at its end, kept or rolled back.
    pub(super) async fn watch(&mut self, pending: &mut Option<Pending>) -> Next {
        let Some(p) = pending else { return Next::Run };
        p.watch.online(&self.health.online_devices());
        let up = self
            .health
            .is_up(&crate::health::Loop::Output(p.watch.connection.clone()));
        let Some(verdict) = p.watch.verdict(Instant::now(), up) else {
            return Next::Run;
        };
        let Some(p) = pending.take() else {
            return Next::Run;
        };
        match verdict {
            Ok(()) => {
                tracing::info!(id = ?p.watch.id, "the pushed config stays: its grace period passed");
                self.finish(&p.watch.id, "kept", None, "its grace period passed".into());
                Next::Run
            }
            Err(why) => self.roll_back(p.record, &why).await,
        }
    }

    /// The previous file back, and in force: applied in place, or by starting again when the
    /// push reached what only a start applies (the new start says the result).
    async fn roll_back(&mut self, mut record: Record, why: &str) -> Next {
        tracing::error!(id = ?record.id, "the pushed config is rolled back: {why}");
        record.rollback = Some(why.to_string());
        self.keep_record(&record);
        let source = self.current.source.clone();
        let restored = files::restore(&record.previous, &source)
            .and_then(|()| Config::load(&source).map_err(|e| e.to_string()));
        let previous = match restored {
            Ok(previous) => previous,
            Err(e) => {
                let message = format!("{why}; and the previous config could not be put back: {e}");
                tracing::error!("{message}");
                self.finish(&record.id, "rolled_back", Some("rollback_failed"), message);
                return Next::Run;
            }
        };
        if crate::remote::reach(&self.current, &previous) == Reach::Restart {
            tracing::warn!(
                "the previous config differs in what only a start applies: starting again"
            );
            return Next::Restart;
        }
        self.take(previous).await;
        let message = format!("rolled back to the previous config: {why}");
        self.finish(&record.id, "rolled_back", Some("rolled_back"), message);
        Next::Run
    }

    /// A push refused before anything changed.
    fn refuse(&self, id: Option<String>, refusal: &Refusal) -> Next {
        tracing::warn!(id = ?id, "a pushed config is refused: {refusal}");
        self.answer(&id, "refused", Some(refusal.code()), refusal.to_string());
        Next::Run
    }

    /// A push's final result, and its record gone.
    fn finish(
        &self,
        id: &Option<String>,
        status: &'static str,
        error: Option<&'static str>,
        message: String,
    ) {
        self.answer(id, status, error, message);
        files::remove_record(&self.current);
    }

    fn keep_record(&self, record: &Record) {
        if let Err(e) = files::save_record(&self.current, record) {
            tracing::error!(
                "cannot keep the pushed config's watch ({e}): a crash now would leave it unwatched"
            );
        }
    }

    /// Says a step on `<root>/config/result`, through every output carrying the JSON topics,
    /// with the hash of the config that runs.
    fn answer(
        &self,
        id: &Option<String>,
        status: &'static str,
        error: Option<&'static str>,
        message: String,
    ) {
        let topics = crate::topics::Topics::new(&self.current.mqtt.topic_root);
        let outcome = ConfigOutcome {
            id: id.clone(),
            status,
            error,
            message,
            hash: Some(self.current.hash().to_string()),
        };
        let reply = crate::command::Reply {
            topics: vec![topics.config_result()],
            correlation: None,
            via: None,
        };
        let _ = self.out.send(crate::reading::Output::CommandResult {
            reply,
            outcome: Outcome::Config(outcome),
        });
    }

    /// Pushes still queued when the process is about to start again: each answered `busy`.
    pub(super) fn refuse_queued(&self, queued: Vec<Incoming>) {
        for msg in queued {
            let id = crate::remote::parse(&msg.payload).ok().and_then(|p| p.id);
            self.refuse(id, &Refusal::Restarting);
        }
    }
}

//! Configs pushed from the broker (`[remote] config = true`), in the running gateway: a push is
//! checked as `pulsegate check` checks a file, refused with every error or written over the
//! config file (the previous kept beside it as `<file>.previous`), applied (buses reloaded,
//! outputs rebuilt; a change only a new start applies starts the process again, and the watch
//! goes on there), and watched for `[remote] grace`: if the connection that delivered it is not
//! up at its end, or a device that answered before has not answered again, the previous file
//! comes back and is applied. Each step is said on `<root>/config/result`.

use std::path::{Path, PathBuf};

use tokio::time::Instant;

use super::Gateway;
use crate::config::Config;
use crate::dispatch::Incoming;
use crate::outcome::{ConfigOutcome, Outcome};
use crate::remote::{Reach, Refusal, Watch};

/// A push in force and being watched, and the file to go back to.
pub(super) struct Pending {
    watch: Watch,
    previous: PathBuf,
}

/// What a restart carries over of a watch (`<state_dir>/remote-pending.json`).
#[derive(serde::Serialize, serde::Deserialize)]
struct Saved {
    id: Option<String>,
    /// The end of the grace period, milliseconds since the Unix epoch.
    until_ms: u64,
    connection: String,
    waiting: Vec<String>,
    previous: PathBuf,
}

fn saved_path(config: &Config) -> PathBuf {
    config.gateway.state_dir.join("remote-pending.json")
}

fn now_ms() -> u64 {
    crate::reading::unix_ms(std::time::SystemTime::now())
}

impl Gateway {
    /// The watch a restart for a pushed config left, if any: it goes on for what is left of
    /// its grace period.
    pub(super) fn resume_watch(&self) -> Option<Pending> {
        resume(&self.current)
    }
}

fn resume(config: &Config) -> Option<Pending> {
    let path = saved_path(config);
    let text = std::fs::read(&path).ok()?;
    let _ = std::fs::remove_file(&path);
    let saved: Saved = match serde_json::from_slice(&text) {
        Ok(s) => s,
        Err(e) => {
            tracing::error!(file = %path.display(), "a pushed config's watch cannot be read ({e}): it is not watched");
            return None;
        }
    };
    let left = std::time::Duration::from_millis(saved.until_ms.saturating_sub(now_ms()));
    tracing::info!(id = ?saved.id, "the pushed config is in force after the restart: watched for {} s more", left.as_secs());
    let mut watch = Watch::new(
        saved.id,
        Instant::now(),
        left,
        &saved.connection,
        &[],
        config,
    );
    watch.waiting = saved.waiting.into_iter().collect();
    Some(Pending {
        watch,
        previous: saved.previous,
    })
}

impl Gateway {
    /// A pushed config: refused, or written, applied and watched. `true` when the process must
    /// start again to apply it (its watch saved for the next start).
    pub(super) async fn push(&mut self, msg: Incoming, pending: &mut Option<Pending>) -> bool {
        let connection = msg.via.as_ref().map_or_else(
            || crate::config::outputs::VOICE_NAME.to_string(),
            |v| v.output.to_string(),
        );
        let push = match crate::remote::parse(&msg.payload) {
            Ok(p) => p,
            Err((id, refusal)) => return self.refuse(id, &refusal),
        };
        if let Some(p) = pending {
            let busy = Refusal::Busy(p.watch.id.clone().unwrap_or_default());
            return self.refuse(push.id, &busy);
        }
        let new = match self.check(&push.toml) {
            Ok(new) => new,
            Err(refusal) => return self.refuse(push.id, &refusal),
        };
        let previous = match self.write(&push.toml) {
            Ok(p) => p,
            Err(e) => return self.refuse(push.id, &Refusal::WriteFailed(e.to_string())),
        };
        let online = self.health.online_devices();
        let grace = new.remote.grace;
        let watch = Watch::new(push.id, Instant::now(), grace, &connection, &online, &new);
        tracing::info!(id = ?watch.id, "a pushed config is in force: watched for {} s", grace.as_secs());
        if crate::remote::reach(&self.current, &new) == Reach::Restart {
            self.save_for_restart(&watch, &previous, grace);
            self.answer(&watch.id, "applied", None, "in force after a restart of the gateway, which starts now; watched for the grace period".into());
            return true;
        }
        self.take(new).await;
        let message = format!("in force; watched for {} s", grace.as_secs());
        self.answer(&watch.id, "applied", None, message);
        *pending = Some(Pending { watch, previous });
        false
    }

    /// Every second of a watch: who answered; at its end, kept or rolled back.
    pub(super) async fn watch(&mut self, pending: &mut Option<Pending>) {
        let Some(p) = pending else { return };
        p.watch.online(&self.health.online_devices());
        let up = self.health.is_up(&format!("output/{}", p.watch.connection));
        let Some(verdict) = p.watch.verdict(Instant::now(), up) else {
            return;
        };
        let Some(p) = pending.take() else { return };
        match verdict {
            Ok(()) => {
                tracing::info!(id = ?p.watch.id, "the pushed config stays: its grace period passed");
                self.answer(&p.watch.id, "kept", None, "its grace period passed".into());
            }
            Err(why) => self.roll_back(p, &why).await,
        }
    }

    /// The previous file back, and in force.
    async fn roll_back(&mut self, p: Pending, why: &str) {
        tracing::error!(id = ?p.watch.id, "the pushed config is rolled back: {why}");
        let source = self.current.source.clone();
        let restored = std::fs::read(&p.previous)
            .and_then(|bytes| write_atomic(&source, &bytes))
            .map_err(|e| e.to_string())
            .and_then(|()| Config::load(&source).map_err(|e| e.to_string()));
        match restored {
            Ok(previous) => {
                self.take(previous).await;
                let message = format!("rolled back to the previous config: {why}");
                self.answer(&p.watch.id, "rolled_back", Some("rolled_back"), message);
            }
            Err(e) => {
                let message = format!("{why}; and the previous config could not be put back: {e}");
                tracing::error!("{message}");
                self.answer(&p.watch.id, "rolled_back", Some("rolled_back"), message);
            }
        }
    }

    /// The pushed text, checked as a file in the config's place would be; secrets and trust
    /// only with `[remote] security`.
    fn check(&self, toml: &str) -> Result<Config, Refusal> {
        let new = Config::from_toml(toml, &self.current.source, None)
            .map_err(|e| Refusal::BadConfig(e.to_string().trim_end().to_string()))?;
        if !self.current.remote.security {
            let guarded = crate::remote::guarded_changes(&self.current, &new);
            if !guarded.is_empty() {
                return Err(Refusal::Forbidden(guarded.join(", ")));
            }
        }
        Ok(new)
    }

    /// The pushed text over the config file, the file in force kept as `<file>.previous`.
    fn write(&self, toml: &str) -> std::io::Result<PathBuf> {
        let source = &self.current.source;
        let previous = PathBuf::from(format!("{}.previous", source.display()));
        let old = std::fs::read(source)?;
        write_atomic(&previous, &old)?;
        write_atomic(source, toml.as_bytes())?;
        Ok(previous)
    }

    fn save_for_restart(&self, watch: &Watch, previous: &Path, grace: std::time::Duration) {
        let saved = Saved {
            id: watch.id.clone(),
            until_ms: now_ms() + grace.as_millis() as u64,
            connection: watch.connection.clone(),
            waiting: watch.waiting.iter().cloned().collect(),
            previous: previous.to_path_buf(),
        };
        let bytes = serde_json::to_vec(&saved).expect("a watch serializes");
        if let Err(e) = write_atomic(&saved_path(&self.current), &bytes) {
            tracing::error!(
                "cannot save the pushed config's watch ({e}): after the restart it is not watched"
            );
        }
    }

    fn refuse(&self, id: Option<String>, refusal: &Refusal) -> bool {
        tracing::warn!(id = ?id, "a pushed config is refused: {refusal}");
        self.answer(&id, "refused", Some(refusal.code()), refusal.to_string());
        false
    }

    /// Says a step on `<root>/config/result`, through every output carrying the JSON topics.
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
}

/// `bytes` over `path`, atomically.
fn write_atomic(path: &Path, bytes: &[u8]) -> std::io::Result<()> {
    let tmp = PathBuf::from(format!("{}.remote-tmp", path.display()));
    crate::state::write_atomic(path, &tmp, bytes)
}

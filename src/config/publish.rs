//! Publish keys at the gateway, device and channel levels (`publish`, `heartbeat`,
//! `min_interval`, `payload`).

use super::walk::{Errors, MAX_DURATION, Table, join};

use crate::config::policy::{PayloadMode, PolicyOverride, PublishMode};

/// Reads `publish`, `heartbeat` and `min_interval` of one table (`"0s"`: none).
pub(crate) fn policy(t: &mut Table<'_>, errs: &mut Errors) -> PolicyOverride {
    let publish = match t.opt::<String>("publish", errs).as_deref() {
        None => None,
        Some("poll") => Some(PublishMode::Poll),
        Some("change") => Some(PublishMode::Change),
        Some(other) => {
            errs.push(
                &join(&t.path, "publish"),
                t.origin(),
                format!("{other:?} is not \"poll\" or \"change\""),
            );
            None
        }
    };
    // "0s" is allowed here: it means none, so a device or channel can undo a wider level's
    // pacing or heartbeat (resolved in `PolicyOverride::policy`).
    let none_or = |t: &mut Table<'_>, key: &str, errs: &mut Errors| {
        t.duration_within(key, std::time::Duration::ZERO, MAX_DURATION, errs)
    };
    PolicyOverride {
        publish,
        heartbeat: none_or(t, "heartbeat", errs),
        min_interval: none_or(t, "min_interval", errs),
    }
}

/// Reads `payload` of one table.
pub(crate) fn payload(t: &mut Table<'_>, errs: &mut Errors) -> Option<PayloadMode> {
    match t.opt::<String>("payload", errs).as_deref() {
        None => None,
        Some("channel") => Some(PayloadMode::Channel),
        Some("device") => Some(PayloadMode::Device),
        Some(other) => {
            errs.push(
                &join(&t.path, "payload"),
                t.origin(),
                format!("{other:?} is not \"channel\" or \"device\""),
            );
            None
        }
    }
}

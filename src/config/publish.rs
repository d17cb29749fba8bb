//! Publish keys at the gateway, device and channel levels (`publish`, `heartbeat`,
//! `min_interval`, `payload`), and `[homeassistant]`.

use super::walk::{Errors, MAX_DURATION, Table, join};
/// The formats `mqtt.format` may name (each built by `publish::formats::build`).
pub const FORMAT_NAMES: &[&str] = &["json", "sparkplug"];

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

/// `[homeassistant]`: MQTT discovery, opt-in.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HomeAssistant {
    pub discovery: bool,
    /// Discovery prefix; Home Assistant announces itself on `<prefix>/status`.
    pub prefix: String,
}

impl Default for HomeAssistant {
    fn default() -> Self {
        HomeAssistant {
            discovery: false,
            prefix: "homeassistant".into(),
        }
    }
}

/// Reads `[homeassistant]`.
pub(crate) fn homeassistant(table: Option<Table<'_>>, errs: &mut Errors) -> HomeAssistant {
    let mut ha = HomeAssistant::default();
    let Some(mut t) = table else { return ha };
    if let Some(v) = t.opt::<bool>("discovery", errs) {
        ha.discovery = v;
    }
    if let Some(p) = t.opt::<String>("prefix", errs) {
        let ok =
            !p.is_empty() && !p.contains(['+', '#']) && p.split('/').all(|level| !level.is_empty());
        if ok {
            ha.prefix = p;
        } else {
            errs.push(
                &join(&t.path, "prefix"),
                t.origin(),
                "must be a topic without wildcards, empty levels or a leading/trailing '/'",
            );
        }
    }
    t.finish(errs);
    ha
}

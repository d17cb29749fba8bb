//! `[homeassistant]`: the settings of the outputs of kind `homeassistant` (MQTT discovery).

use std::sync::Arc;

use super::kind::{Context, Kind, OwnTable, Settings};
use crate::config::walk::{Errors, Table, join};

/// The kind's part of the config: the JSON topics with discovery configs beside them, set up by
/// `[homeassistant]` (optional); its discovery prefix is no place for a command's response.
pub static KIND: Kind = Kind {
    name: "homeassistant",
    gateway_topics: true,
    table: Some(OwnTable {
        name: "homeassistant",
        read: read_table,
        needed: None,
    }),
    reserved: |settings| {
        let ha = settings.and_then(|s| s.as_any().downcast_ref::<HomeAssistant>());
        let prefix = ha.map_or_else(|| HomeAssistant::default().prefix, |h| h.prefix.clone());
        Some((prefix, "it is under the Home Assistant discovery prefix"))
    },
};

/// `[homeassistant]`, checked.
#[derive(Debug, Clone, Eq)]
pub struct HomeAssistant {
    /// Discovery prefix; Home Assistant announces itself on `<prefix>/status`.
    pub prefix: String,
    /// `discovery`: `mqtt.format`'s way of asking for an output of kind `homeassistant`.
    pub discovery: Option<bool>,
}

/// By the prefix: `discovery` shows in the outputs' list (a reload that only writes out
/// `discovery = false` changes no output).
impl PartialEq for HomeAssistant {
    fn eq(&self, other: &HomeAssistant) -> bool {
        self.prefix == other.prefix
    }
}

impl Default for HomeAssistant {
    fn default() -> Self {
        HomeAssistant {
            prefix: "homeassistant".into(),
            discovery: None,
        }
    }
}

fn read_table(
    table: Option<Table<'_>>,
    _: &Context<'_>,
    errs: &mut Errors,
) -> Option<Arc<dyn Settings>> {
    Some(Arc::new(read(table, errs)))
}

/// Reads `[homeassistant]`, and its `discovery` key when present.
pub(crate) fn read(table: Option<Table<'_>>, errs: &mut Errors) -> HomeAssistant {
    let mut ha = HomeAssistant::default();
    let Some(mut t) = table else {
        return ha;
    };
    ha.discovery = t.opt::<bool>("discovery", errs);
    if let Some(p) = t.opt::<String>("prefix", errs) {
        if crate::topics::is_topic_prefix(&p) {
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

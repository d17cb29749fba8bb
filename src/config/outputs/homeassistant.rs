//! `[homeassistant]`: the settings of the outputs of kind `homeassistant` (MQTT discovery).

use crate::config::walk::{Errors, Table, join};

/// `[homeassistant]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct HomeAssistant {
    /// Discovery prefix; Home Assistant announces itself on `<prefix>/status`.
    pub prefix: String,
}

impl Default for HomeAssistant {
    fn default() -> Self {
        HomeAssistant {
            prefix: "homeassistant".into(),
        }
    }
}

/// Reads `[homeassistant]`, and its `discovery` key (`mqtt.format`'s way of asking for an
/// output of kind `homeassistant`) when present.
pub(crate) fn read(table: Option<Table<'_>>, errs: &mut Errors) -> (HomeAssistant, Option<bool>) {
    let mut ha = HomeAssistant::default();
    let Some(mut t) = table else {
        return (ha, None);
    };
    let discovery = t.opt::<bool>("discovery", errs);
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
    (ha, discovery)
}

//! `[sparkplug]`: the settings of the outputs of kind `sparkplug` (the gateway as a Sparkplug B
//! edge node).

use std::sync::Arc;

use super::kind::{Context, Kind, OwnTable, Settings};
use crate::config::walk::{Errors, Table, join};

/// The topic namespace of Sparkplug B.
pub const NAMESPACE: &str = "spBv1.0";

/// The kind's part of the config: `[sparkplug]`, needed exactly when an output is of this kind;
/// the Sparkplug B namespace is no place for a command's response.
pub static KIND: Kind = Kind {
    name: "sparkplug",
    gateway_topics: false,
    table: Some(OwnTable {
        name: "sparkplug",
        read: read_table,
        needed: Some("with its group_id"),
    }),
    reserved: |_| {
        let why = "it is in the Sparkplug B namespace (births, data and deaths of nodes)";
        Some((NAMESPACE.to_string(), why))
    },
};

fn read_table(
    table: Option<Table<'_>>,
    cx: &Context<'_>,
    errs: &mut Errors,
) -> Option<Arc<dyn Settings>> {
    let s = sparkplug(table, cx.gateway_id, errs)?;
    Some(Arc::new(s))
}

/// `[sparkplug]`, checked.
#[derive(Debug, Clone, PartialEq, Eq)]
pub struct Sparkplug {
    /// `spBv1.0/<group_id>/…`: the group the SCADA host files this node under.
    pub group_id: String,
    /// The node's id in its group (default: the gateway id).
    pub edge_node_id: String,
    /// The primary host whose `spBv1.0/STATE/<host>` births wait for.
    pub primary_host: Option<String>,
}

/// A Sparkplug id (group, edge node, device, host): a topic level of its own, so no `/`, and no
/// wildcard (spec 3.0, "Topic Namespace Elements"); nothing invisible, at most 64 bytes.
pub fn is_sparkplug_id(id: &str) -> bool {
    crate::topics::is_topic_level(id, 64)
}

/// Reads `[sparkplug]`; `None` when it is absent or broken (every problem in `errs`).
pub(crate) fn sparkplug(
    table: Option<Table<'_>>,
    gateway_id: &str,
    errs: &mut Errors,
) -> Option<Sparkplug> {
    let mut t = table?;
    let group_id = t.req::<String>("group_id", errs);
    let group_id = group_id.and_then(|v| checked_id(&t, "group_id", v, errs));
    let edge_node_id = t.opt::<String>("edge_node_id", errs);
    let edge_node_id = edge_node_id.and_then(|v| checked_id(&t, "edge_node_id", v, errs));
    let primary_host = t.opt::<String>("primary_host", errs);
    let primary_host = primary_host.and_then(|v| checked_id(&t, "primary_host", v, errs));
    t.finish(errs);
    Some(Sparkplug {
        group_id: group_id?,
        edge_node_id: edge_node_id.unwrap_or_else(|| gateway_id.to_string()),
        primary_host,
    })
}

/// `value` of `key` when it is a Sparkplug id.
fn checked_id(t: &Table<'_>, key: &str, value: String, errs: &mut Errors) -> Option<String> {
    if is_sparkplug_id(&value) {
        return Some(value);
    }
    let why = format!(
        "{value:?} is not a Sparkplug id: 1..64 bytes without '/', '+', '#' or control characters"
    );
    errs.push(&join(&t.path, key), t.origin(), why);
    None
}

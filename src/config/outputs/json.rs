//! The output kind `json`: the gateway's JSON topics (`<root>/<device>/<channel>`, statuses,
//! intervals). No table of its own; it carries the gateway's topics (and so its voice).

use super::kind::{Kind, reserves_nothing};

/// The kind's part of the config.
pub static KIND: Kind = Kind {
    name: "json",
    gateway_topics: true,
    table: None,
    reserved: reserves_nothing,
};

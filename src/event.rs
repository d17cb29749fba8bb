//! What happened to a channel's count besides counting: the word the counter finds, metering
//! records, the state file keeps and the payloads carry. Pure.

use serde::{Deserialize, Serialize};

/// Something other than counting happened on a channel.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Event {
    /// The count wrapped around its range (a 16/32-bit count; a meter register rolled over).
    Rollover,
    /// The module restarted or someone else cleared it; delta is the count since then.
    Reset,
    /// The gateway cleared the channel.
    Cleared,
    /// The gateway preset the channel.
    Preset,
    /// The gateway or the device was away; the delta covers the whole gap.
    Gap,
}

//! What of a server output an unsigned pushed config may not change (`remote/guard.rs` asks):
//! what it listens on, who may connect, whether writes are taken, and the register map's
//! places (a contract with the PLC programs that read it).

use super::map::RegisterMap;
use crate::config::model::Config;

/// The trust-moving changes of the server outputs from `old` to `new`, in words.
pub fn changes(old: &Config, new: &Config) -> Vec<String> {
    let mut out = Vec::new();
    if !old.outputs.servers.modbus.is_empty() {
        out.extend(moved_registers(old, new));
    }
    if old.outputs.servers.modbus != new.outputs.servers.modbus {
        out.push("outputs of kind modbus (what the gateway listens on, who may connect, whether writes are taken)".to_string());
    }
    out
}

/// The register map is a contract with the PLC programs that read it: an unsigned push may add
/// to it (a device, a channel) but not move or drop what a PLC reads.
fn moved_registers(old: &Config, new: &Config) -> Option<String> {
    let after = RegisterMap::of(new).entries(true);
    let moved: Vec<String> = RegisterMap::of(old)
        .entries(true)
        .into_iter()
        .filter(|e| !after.contains(e))
        .map(|e| format!("{}/{}", e.device, e.channel.as_deref().unwrap_or("-")))
        .collect::<std::collections::BTreeSet<_>>()
        .into_iter()
        .collect();
    (!moved.is_empty()).then(|| {
        format!(
            "the Modbus server's register map (moves or drops {}: a PLC would read something else)",
            moved.join(", ")
        )
    })
}

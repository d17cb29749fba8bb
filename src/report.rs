//! The compiled poll plan in words, for `pulsegate check` and `pulsegate plan`: each bus in its
//! protocol's words (`Protocol::in_words`), then the outputs. Pure.

use std::fmt::Write;

use crate::config::Config;

/// Each bus in its protocol's words, then where readings go.
pub fn poll_plan(config: &Config) -> String {
    let mut out = String::new();
    for bus in &config.buses {
        out += &bus.link.protocol().in_words(bus);
    }
    out + &outputs(config)
}

/// Where readings go: each output, its kind, its broker and client id, and where the gateway's
/// own voice is said.
fn outputs(config: &Config) -> String {
    use crate::config::outputs::{VOICE_NAME, VoiceHome};
    let mut out = String::new();
    for (i, o) in config.outputs.list.iter().enumerate() {
        let voice = match config.outputs.voice {
            VoiceHome::Output(v) if v == i => ", with the gateway's status and commands",
            _ if o.kind.carries_gateway_topics() => ", with the gateway's status",
            _ => "",
        };
        let _ = writeln!(
            out,
            "output {} ({}): {} as {}{voice}",
            o.name,
            o.kind,
            o.mqtt.broker(),
            o.mqtt.client_id
        );
    }
    if config.outputs.voice == VoiceHome::Own {
        let m = &config.mqtt;
        let _ = writeln!(
            out,
            "{VOICE_NAME} (the gateway's status and commands): {} as {}",
            m.broker(),
            m.client_id
        );
    }
    out
}

/// The register map of the server outputs (docs/plc.md): a table, or with `json` a JSON
/// list of `{"device", "channel", "field", "unit_id", "table", "address", "registers", "type"}`.
pub fn register_map(config: &Config, json: bool) -> String {
    use crate::config::buses::RegisterMap;
    let commands = config.outputs.serve_commands();
    let entries = RegisterMap::of(config).entries(commands);
    if json {
        let text = serde_json::to_string_pretty(&entries).unwrap_or_else(|_| "[]".into());
        return format!("{text}\n");
    }
    let mut out = String::from("unit  table    address  regs  type     device / channel / field\n");
    for e in &entries {
        let what = match &e.channel {
            Some(c) => format!("{} / {c} / {}", e.device, e.field),
            None => format!("{} / - / {}", e.device, e.field),
        };
        out.push_str(&format!(
            "{:>4}  {:<7}  {:>7}  {:>4}  {:<7}  {what}\n",
            e.unit_id, e.table, e.address, e.registers, e.ty
        ));
    }
    out
}

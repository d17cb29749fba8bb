//! The compiled poll plan in words, for `pulsegate check` and `pulsegate plan`. Pure.

use std::fmt::Write;
use std::time::Duration;

use crate::config::{Config, Device, Link};
use crate::plan::{PollPlan, Wire, line_time};
use crate::profile::Register;

/// Assumed device turnaround when estimating line time (the bus measures it at run time).
const TURNAROUND: Duration = crate::plan::DEFAULT_TURNAROUND;

/// One line per device with its reads, registers and line time per poll, and per bus the share
/// of the line its intervals need (a warning when above 100%). Work modes are not known before
/// the modules answer, so each group is taken in its first mode.
pub fn poll_plan(config: &Config) -> String {
    let mut out = String::new();
    for bus in &config.buses {
        let timing = bus.line_timing();
        let link = &bus.link;
        if let Link::Mbus(_) = link {
            let _ = writeln!(out, "{}", meters(&bus.name, link, &bus.devices));
            continue;
        }
        let _ = writeln!(out, "bus {} ({link}):", bus.name);
        let wire = Wire::for_line(timing.as_ref());
        let mut load = 0.0;
        for d in &bus.devices {
            let modes: Vec<u16> = vec![0; d.profile.mode_registers().len()];
            let channels = d.profile.channels(&modes).unwrap_or_default();
            let values: Vec<Register> = channels.iter().flat_map(|c| c.polled()).collect();
            // The same value the bus builds and executes for this mode.
            let plan = PollPlan::new(&values, &[], &wire);
            let time = timing.map(|t| line_time(&plan.blocks, &t, TURNAROUND));
            if let Some(t) = time {
                load += t.as_secs_f64() / d.poll.as_secs_f64();
            }
            let _ = writeln!(
                out,
                "  {:<16} unit {:>3} {:<10} every {:<8} {}, {} channels{}",
                d.name,
                d.unit,
                d.profile.model,
                humantime::format_duration(d.poll).to_string(),
                plan.describe(),
                channels.len(),
                time.map(|t| format!(", {:.1} ms on the line", t.as_secs_f64() * 1000.0))
                    .unwrap_or_default(),
            );
        }
        if timing.is_some() {
            let _ = writeln!(out, "  line use at these intervals: {:.0}%", load * 100.0);
            if load > 1.0 {
                let _ = writeln!(
                    out,
                    "  WARNING: bus {} cannot meet its poll intervals at this baud rate",
                    bus.name
                );
            }
        }
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

/// An M-Bus bus in words: its line and each meter's address and poll interval (a meter's
/// channels are its answer's records, known when it answers).
fn meters(bus: &str, link: &Link, devices: &[Device]) -> String {
    let mut out = format!("bus {bus} ({link}):");
    for d in devices {
        let address = d.address.to_string();
        let picked = d.channels.values().filter(|c| c.record.is_some()).count();
        let records = match picked {
            0 => "every record a channel".to_string(),
            n => format!("{n} records picked"),
        };
        out += &format!(
            "\n  {:<16} {address:<22} every {:<8} {records}",
            d.name,
            humantime::format_duration(d.poll).to_string()
        );
    }
    out
}

/// The register map of the Modbus server outputs (docs/plc.md): a table, or with `json` a JSON
/// list of `{"device", "channel", "field", "unit_id", "table", "address", "registers", "type"}`.
pub fn register_map(config: &Config, json: bool) -> String {
    use crate::config::outputs::modbus::map::RegisterMap;
    let commands = config.outputs.modbus.iter().any(|s| s.commands);
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

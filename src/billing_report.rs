//! `pulsegate billing`: the billing periods each metered channel keeps in the state files, in
//! words or as JSON lines. Reads the files only; the running gateway is not asked.

use std::fmt::Write;

use serde::Serialize;

use crate::config::Config;
use crate::metering::billing::{BillingRecord, PeriodStatus};
use crate::metering::clock::iso;
use crate::state::{BusState, bus_path, split_channel_key};

/// One kept period of one channel, as `--json` prints it.
#[derive(Debug, Serialize)]
struct Line<'a> {
    device: &'a str,
    channel: &'a str,
    start: String,
    end: String,
    total_start: i64,
    total_end: i64,
    delta: i64,
    #[serde(skip_serializing_if = "std::collections::BTreeMap::is_empty")]
    by_tariff: &'a std::collections::BTreeMap<String, i64>,
    #[serde(skip_serializing_if = "Option::is_none")]
    demand: Option<Demand>,
    status: PeriodStatus,
    seq: u64,
}

#[derive(Debug, Serialize)]
struct Demand {
    value: String,
    unit: String,
    start: String,
}

/// The last `n` periods of every channel, oldest first per channel.
pub fn billing(config: &Config, json: bool, n: usize) -> Result<String, String> {
    let mut out = String::new();
    for bus in &config.buses {
        let path = bus_path(&config.gateway.state_dir, &bus.name);
        if !path.exists() {
            continue;
        }
        let state = BusState::inspect(&path).map_err(|e| format!("{}: {e}", path.display()))?;
        for (key, ch) in &state.channels {
            let Some((unit, model, channel)) = split_channel_key(key) else {
                continue;
            };
            let Some(d) = bus
                .devices
                .iter()
                .find(|d| d.unit.to_string() == unit && d.model == model)
            else {
                continue;
            };
            let Some(account) = &ch.account else { continue };
            let units = d.channels.get(channel).map(|c| &c.units);
            let kept = &account.kept[account.kept.len().saturating_sub(n)..];
            for b in kept {
                let line = line(&d.name, channel, b, units);
                if json {
                    let _ = writeln!(out, "{}", serde_json::to_string(&line).unwrap_or_default());
                } else {
                    words(&mut out, &line);
                }
            }
        }
    }
    Ok(out)
}

fn line<'a>(
    device: &'a str,
    channel: &'a str,
    b: &'a BillingRecord,
    units: Option<&crate::config::units::ChannelUnits>,
) -> Line<'a> {
    let scale = units.and_then(|u| u.scale.as_ref());
    let unit = units
        .filter(|u| u.scale.is_some())
        .and_then(|u| u.unit.as_deref());
    Line {
        device,
        channel,
        start: iso(b.start_ms),
        end: iso(b.end_ms),
        total_start: b.total_start,
        total_end: b.total_end,
        delta: b.delta,
        by_tariff: &b.by_tariff,
        demand: b.peak.map(|p| Demand {
            value: crate::metering::demand::rate(&p, scale).to_string(),
            unit: crate::metering::demand::rate_unit(unit),
            start: iso(p.start_ms),
        }),
        status: b.status,
        seq: b.seq,
    }
}

fn words(out: &mut String, l: &Line<'_>) {
    let status = serde_json::to_string(&l.status).unwrap_or_default();
    let _ = write!(
        out,
        "{}/{}  #{}  {} .. {}  {}  delta {}",
        l.device,
        l.channel,
        l.seq,
        l.start,
        l.end,
        status.trim_matches('"'),
        l.delta
    );
    for (t, n) in l.by_tariff {
        let _ = write!(out, "  {t} {n}");
    }
    if let Some(d) = &l.demand {
        let _ = write!(out, "  demand {} {} from {}", d.value, d.unit, d.start);
    }
    out.push('\n');
}

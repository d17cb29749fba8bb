//! Commissioning an M-Bus segment: `pulsegate scan --protocol mbus` (primary addresses one by
//! one, or `--secondary`: the standard's wildcard search, collisions resolved digit by digit)
//! and `pulsegate read --protocol mbus` (one meter's answer, every record with its value in its
//! unit), over the gateway's own M-Bus master.

pub(crate) mod commands;

use std::collections::BTreeMap;
use std::fmt::Write as _;
use std::time::Duration;

use serde_json::{Value, json};

use crate::commission::error::CommissionError;
use crate::commission::target::Target;
use crate::config::Parity;
use crate::mbus::config::Line as MbusLine;
use crate::mbus::driver::address::{SecondaryMask, medium_name};
use crate::mbus::driver::channel::{self, Kind};
use crate::mbus::driver::header::Header;
use crate::mbus::driver::master::link::Link;
use crate::mbus::driver::master::search::{self, FoundMeter, Probe, Step};
use crate::mbus::driver::master::{Address, MeterDevice};
use crate::mbus::driver::value::Value as RecordValue;
use crate::mbus::driver::{Record, master};

/// Where and how to reach the segment.
#[derive(Debug, Clone)]
pub struct Segment {
    pub target: Target,
    pub baud: u32,
    pub timeout: Option<Duration>,
}

impl Segment {
    /// The master's line (a TCP converter needs HOST:PORT).
    fn link(&self, host_given: Option<&str>) -> Result<Link, CommissionError> {
        self.target.check_free()?;
        let line = match &self.target {
            Target::Serial { port, parity } => MbusLine::Serial {
                port: port.clone(),
                baud: self.baud,
                parity: *parity,
            },
            Target::Tcp { host, port } => {
                if host_given.is_some_and(|h| !h.contains(':')) {
                    return Err(CommissionError::BadInput(
                        "--host: an M-Bus converter's address is HOST:PORT".into(),
                    ));
                }
                MbusLine::Tcp {
                    host: host.clone(),
                    port: *port,
                }
            }
        };
        Ok(Link::new(line, self.timeout))
    }
}

/// What a scan asks: primary addresses, or the wildcard search.
pub struct MeterScan {
    pub secondary: bool,
    pub addresses: Vec<u8>,
}

/// Primary addresses from "0-250", "5" or "1,3,10-20".
pub fn parse_addresses(text: &str) -> Result<Vec<u8>, CommissionError> {
    let bad = |why: String| CommissionError::BadInput(format!("--units {text:?}: {why}"));
    let mut out = Vec::new();
    for part in text.split(',') {
        let (lo, hi) = part
            .trim()
            .split_once('-')
            .unwrap_or((part.trim(), part.trim()));
        let parse = |s: &str| {
            s.trim()
                .parse::<u8>()
                .ok()
                .filter(|a| *a <= crate::mbus::config::MAX_PRIMARY)
                .ok_or_else(|| bad(format!("{s:?} is not a primary address (0-250)")))
        };
        let (lo, hi) = (parse(lo)?, parse(hi)?);
        if lo > hi {
            return Err(bad(format!("{lo}-{hi} runs backwards")));
        }
        out.extend(lo..=hi);
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

/// Finds the meters of a segment; `progress` hears each step. Returns what was found (in id
/// order for a secondary search, address order for a primary one), the collisions met, and
/// problems (a meter that answers something that is no telegram).
pub async fn scan(
    segment: &Segment,
    host: Option<&str>,
    how: &MeterScan,
    cancel: &tokio_util::sync::CancellationToken,
    mut progress: impl FnMut(&str),
) -> Result<(Vec<FoundMeter>, usize, Vec<String>), CommissionError> {
    let mut link = segment.link(host)?;
    let failed = |e: master::link::LinkError| CommissionError::Failed(e.to_string());
    if how.secondary {
        let searched = search::secondary(&mut link, |step| {
            match step {
                Step::Asked(mask) => progress(&format!("select {mask}")),
                Step::Collision(mask) => progress(&format!("{mask}: several meters answer")),
                Step::Found(m) => progress(&format!("found {}", describe(m))),
            }
            !cancel.is_cancelled()
        })
        .await
        .map_err(failed)?;
        return Ok((searched.found, searched.collisions, searched.problems));
    }
    let (mut found, mut problems) = (Vec::new(), Vec::new());
    for a in &how.addresses {
        if cancel.is_cancelled() {
            break;
        }
        progress(&format!("address {a}"));
        match search::probe_primary(&mut link, *a).await.map_err(failed)? {
            Probe::Nothing => {}
            Probe::Found(m) => {
                progress(&format!("found {}", describe(&m)));
                found.push(*m);
            }
            Probe::Garbled(why) => problems.push(format!(
                "address {a}: garbled answer ({why}): several meters at this address? \
                 Use --secondary"
            )),
            Probe::Undecodable(why) => problems.push(format!("address {a}: {why}")),
        }
    }
    Ok((found, 0, problems))
}

fn describe(m: &FoundMeter) -> String {
    match m.secondary {
        Some(s) => format!(
            "{} {} at address {}",
            s.id_text(),
            s.manufacturer_code(),
            m.primary
        ),
        None => format!("a meter at address {}", m.primary),
    }
}

/// A found meter as JSON: id, manufacturer, version, medium, address, records.
pub fn found_json(m: &FoundMeter) -> Value {
    let s = m.secondary;
    json!({
        "address": m.primary,
        "id": s.map(|s| s.id_text()),
        "manufacturer": s.map(|s| s.manufacturer_code()),
        "version": s.map(|s| s.version),
        "medium": search::medium(m),
        "medium_name": search::medium(m).map(medium_name),
        "records": channel::names(&m.telegram.records),
    })
}

/// The table of what a scan found.
pub fn found_table(found: &[FoundMeter]) -> String {
    let mut t = format!(
        "{:>7}  {:<8}  {:<12}  {:>7}  {}\n",
        "address", "id", "manufacturer", "version", "medium"
    );
    for m in found {
        let s = m.secondary;
        let medium = search::medium(m)
            .map(|c| format!("{c:02X} {}", medium_name(c)))
            .unwrap_or_default();
        let _ = writeln!(
            t,
            "{:>7}  {:<8}  {:<12}  {:>7}  {medium}",
            m.primary,
            s.map(|s| s.id_text()).unwrap_or_else(|| "-".into()),
            s.map(|s| s.manufacturer_code())
                .unwrap_or_else(|| "-".into()),
            s.map(|s| s.version.to_string())
                .unwrap_or_else(|| "-".into()),
        );
    }
    let _ = writeln!(t, "{} meter(s) found", found.len());
    t
}

/// A whole config file (gateway, MQTT, one M-Bus bus) for the meters found: each by its
/// primary address where it alone answers there, else by its id (and manufacturer).
/// The keys of the scanned segment's bus: its serial port or its TCP converter.
fn bus_keys(segment: &Segment) -> String {
    match &segment.target {
        Target::Serial { port, parity } => {
            let p = match parity {
                Parity::None => "none",
                Parity::Even => "even",
                Parity::Odd => "odd",
            };
            format!(
                "port = {:?}\nbaud = {}\nparity = \"{p}\"\n",
                port.display().to_string(),
                segment.baud
            )
        }
        Target::Tcp { host, port } => format!("host = \"{host}:{port}\"\n"),
    }
}

pub fn config_snippet(segment: &Segment, found: &[FoundMeter]) -> String {
    let mut t = String::from(
        "# Written by `pulsegate scan --protocol mbus --toml`. Check it with \
         `pulsegate check --config FILE`.\n[gateway]\n# id = \"<host name>\"\n\
         state_dir = \"/var/lib/pulsegate\"\n\n[mqtt]\nhost = \"127.0.0.1\"\nport = 1883\n\n",
    );
    if found.is_empty() {
        t += "# No meter answered, so there is no bus here yet.\n";
        return t;
    }
    t += "[buses.mbus1]\nprotocol = \"mbus\"\n";
    t += &bus_keys(segment);
    let mut at: BTreeMap<u8, usize> = BTreeMap::new();
    for m in found {
        *at.entry(m.primary).or_default() += 1;
    }
    let mut names: BTreeMap<String, usize> = BTreeMap::new();
    for (i, m) in found.iter().enumerate() {
        let shared = at[&m.primary] > 1 || m.primary == 0;
        let base = match m.secondary {
            Some(s) => format!("{}_{}", s.manufacturer_code().to_lowercase(), s.id_text()),
            None => format!("meter_{}", m.primary),
        };
        let n = names.entry(base.clone()).or_default();
        *n += 1;
        let name = if *n == 1 {
            base
        } else {
            format!("{base}_{}", i + 1)
        };
        let name: String = name
            .chars()
            .map(|c| if c.is_ascii_alphanumeric() { c } else { '_' })
            .collect();
        let _ = writeln!(t, "\n[buses.mbus1.devices.{name}]");
        match (m.secondary, shared) {
            (Some(s), true) => {
                let _ = writeln!(t, "id = \"{}\"", s.id_text());
                if s.manufacturer_code()
                    .chars()
                    .all(|c| c.is_ascii_uppercase())
                {
                    let _ = writeln!(t, "manufacturer = \"{}\"", s.manufacturer_code());
                }
            }
            _ => {
                let _ = writeln!(t, "address = {}", m.primary);
            }
        }
        let _ = writeln!(t, "poll = \"60s\"");
        let _ = writeln!(
            t,
            "# records: {}",
            channel::names(&m.telegram.records).join(" ")
        );
    }
    t
}

/// Where `read` finds its meter: `--address N` or `--id ID` (wildcards F allowed).
pub fn meter_at(address: Option<u8>, id: Option<&str>) -> Result<Address, CommissionError> {
    match (address, id) {
        (Some(a), None) => Ok(Address::Primary(a)),
        (None, Some(id)) => SecondaryMask::from_id(id)
            .map(Address::Secondary)
            .map_err(|e| CommissionError::BadInput(format!("--id: {e}"))),
        _ => Err(CommissionError::BadInput(
            "give --address N (primary) or --id ID (secondary) of the meter".into(),
        )),
    }
}

/// Reads one meter's whole answer: its header and records.
pub async fn read(
    segment: &Segment,
    host: Option<&str>,
    at: Address,
) -> Result<(Header, Vec<Record>), CommissionError> {
    let mut link = segment.link(host)?;
    let mut meter = MeterDevice::at(at);
    let (header, records) = meter
        .read_out(&mut link)
        .await
        .map_err(|e| CommissionError::Failed(e.to_string()))?;
    if let Address::Secondary(_) = at {
        // Leave nothing selected behind.
        let _ = link
            .exchange(&crate::mbus::driver::frame::snd_nke(0xFD))
            .await;
    }
    Ok((header, records))
}

/// `{"id","manufacturer","version","medium","access","status","records":[…]}`.
pub fn answer_json(header: &Header, records: &[Record]) -> Value {
    let (id, manufacturer, version, medium, access, status) = match *header {
        Header::Long {
            address,
            access,
            status,
            ..
        } => (
            Some(address.id_text()),
            Some(address.manufacturer_code()),
            Some(address.version),
            Some(address.medium),
            Some(access),
            Some(status),
        ),
        Header::Short { access, status, .. } => {
            (None, None, None, None, Some(access), Some(status))
        }
        Header::Fixed {
            id,
            access,
            status,
            medium,
        } => (
            Some(format!("{id:08X}")),
            None,
            None,
            Some(medium),
            Some(access),
            Some(status),
        ),
        Header::None => (None, None, None, None, None, None),
    };
    json!({
        "id": id,
        "manufacturer": manufacturer,
        "version": version,
        "medium": medium,
        "access": access,
        "status": status,
        "records": records.iter().map(record_json).collect::<Vec<_>>(),
    })
}

/// One record: `value` a number where the record is numeric (its exact decimal text), in
/// `unit`; a date, text or bytes as a string.
fn record_json(r: &Record) -> Value {
    let value = match &r.value {
        RecordValue::Number(e) => e
            .to_decimal_string()
            .parse::<serde_json::Number>()
            .map(Value::Number)
            .unwrap_or(Value::Null),
        RecordValue::Real { .. } => r
            .value
            .to_f64()
            .and_then(serde_json::Number::from_f64)
            .map_or(Value::Null, Value::Number),
        RecordValue::Date(d) => d.to_string().into(),
        RecordValue::DateTime(d) => d.to_string().into(),
        RecordValue::Text(t) => t.clone().into(),
        RecordValue::InvalidBcd(d) => d.clone().into(),
        RecordValue::Bytes(b) => b
            .iter()
            .map(|x| format!("{x:02X}"))
            .collect::<String>()
            .into(),
        RecordValue::Empty => Value::Null,
    };
    json!({
        "index": r.index,
        "quantity": r.quantity().name(),
        "function": r.function.name(),
        "storage": r.storage,
        "tariff": r.tariff,
        "subunit": r.subunit,
        "unit": r.unit().map(|u| u.symbol()),
        "value": value,
    })
}

/// The answer as a table: each record's default channel name, value and unit, and whether the
/// gateway counts it.
pub fn answer_table(answer: &Value, records: &[Record]) -> String {
    let mut t = String::new();
    let _ = writeln!(
        t,
        "meter {} {} version {} medium {}",
        answer["id"].as_str().unwrap_or("-"),
        answer["manufacturer"].as_str().unwrap_or("-"),
        answer["version"],
        answer["medium"]
    );
    for ((r, name), json) in records
        .iter()
        .zip(channel::names(records))
        .zip(answer["records"].as_array().into_iter().flatten())
    {
        let counted = match channel::kind(r) {
            Kind::Register(_) => "  (register: counted)",
            Kind::Value => "",
        };
        let _ = writeln!(
            t,
            "{:>3}  {name:<32} {} {}{counted}",
            r.index,
            json["value"],
            json["unit"].as_str().unwrap_or("")
        );
    }
    t
}

//! `[tariffs]` and `[billing]`: the time-of-use calendar and the billing periods, checked
//! against every metered channel's intervals (a rule time must be a boundary of each channel's
//! shortest interval, so every record lies in one tariff).

use std::path::PathBuf;
use std::sync::Arc;

use super::model::{Bus, Gateway};
use super::walk::{Errors, Table, join};
use crate::metering::Period;
use crate::metering::billing::{BillingConfig, Cycle};
use crate::metering::tariff::{Calendar, RawRule};
use crate::signing::SigningKey;

/// Reads `[tariffs]` and `[billing]` of the root table.
pub(crate) fn read(
    root: &mut Table<'_>,
    errs: &mut Errors,
) -> (Option<Arc<Calendar>>, Option<Arc<BillingConfig>>) {
    let calendar = root.table("tariffs", errs).and_then(|t| tariffs(t, errs));
    let billing = root.table("billing", errs).and_then(|t| billing(t, errs));
    (calendar.map(Arc::new), billing.map(Arc::new))
}

fn tariffs(mut t: Table<'_>, errs: &mut Errors) -> Option<Calendar> {
    let default = t.req::<String>("default", errs);
    let holidays = t.opt::<Vec<String>>("holidays", errs).unwrap_or_default();
    let rules = t.opt::<Vec<RawRule>>("rule", errs).unwrap_or_default();
    let origin = t.origin().map(str::to_string);
    let path = t.path.clone();
    t.finish(errs);
    let names = default.iter().chain(rules.iter().map(|r| &r.tariff));
    for n in names.filter(|n| !crate::topics::is_topic_safe(n)) {
        errs.push(
            &path,
            origin.as_deref(),
            format!(
                "{n:?} is not a tariff name: letters, digits, '-' or '_' (it is a topic level)"
            ),
        );
    }
    match Calendar::new(&default?, &holidays, &rules) {
        Ok(c) => Some(c),
        Err(list) => {
            for (rule, e) in list {
                let at = match rule {
                    Some(i) => format!("{path}.rule[{}]", i + 1),
                    None => path.clone(),
                };
                errs.push(&at, origin.as_deref(), e.to_string());
            }
            None
        }
    }
}

fn billing(mut t: Table<'_>, errs: &mut Errors) -> Option<BillingConfig> {
    let path = t.path.clone();
    let period = t.opt::<String>("period", errs);
    let day = t.int::<i8>("day", errs);
    let cycle = match (period.as_deref(), day) {
        (Some("daily"), None) => Some(Cycle::Daily),
        (Some("daily"), Some(_)) => {
            errs.push(&join(&path, "day"), t.origin(), "a daily period has no day");
            None
        }
        (Some("monthly") | None, d) => match d.unwrap_or(1) {
            day @ 1..=28 => Some(Cycle::Monthly { day }),
            _ => {
                errs.push(
                    &join(&path, "day"),
                    t.origin(),
                    "must be 1 to 28 (every month has it)",
                );
                None
            }
        },
        (Some(other), _) => {
            errs.push(
                &join(&path, "period"),
                t.origin(),
                format!("{other:?} is not a billing period: \"daily\" or \"monthly\""),
            );
            None
        }
    };
    let demand = t.opt::<String>("demand", errs).and_then(|text| {
        let p = Period::parse(&text)
            .map_err(|e| errs.push(&join(&path, "demand"), t.origin(), e.to_string()))
            .ok()?;
        if 3_600_000 % p.ms() != 0 {
            errs.push(
                &join(&path, "demand"),
                t.origin(),
                format!("{text:?} does not divide an hour: demand is a mean power per hour"),
            );
            return None;
        }
        Some(p)
    });
    let signing_key = t.opt::<PathBuf>("signing_key", errs);
    let signer = signing_key.as_deref().and_then(|file| {
        read_key(file)
            .map_err(|e| errs.push(&join(&path, "signing_key"), t.origin(), e))
            .ok()
    });
    t.finish(errs);
    Some(BillingConfig {
        cycle: cycle?,
        demand,
        signing_key,
        signer,
    })
}

/// The Ed25519 key of `[billing] signing_key`, read once when the config is checked.
fn read_key(file: &std::path::Path) -> Result<Arc<SigningKey>, String> {
    let text = std::fs::read_to_string(file)
        .map_err(|e| format!("cannot read the signing key {}: {e}", file.display()))?;
    SigningKey::from_pem(&text)
        .map(Arc::new)
        .map_err(|e| format!("{}: {e}", file.display()))
}

/// Every interval list that applies to some channel, with where it is written.
fn interval_lists<'a>(gateway: &'a Gateway, buses: &'a [Bus]) -> Vec<(String, &'a [Period])> {
    let mut out = Vec::new();
    if let Some(g) = &gateway.intervals {
        out.push(("gateway.intervals".to_string(), g.as_slice()));
    }
    for bus in buses {
        for d in &bus.devices {
            let at = format!("buses.{}.devices.{}", bus.name, d.name);
            if let Some(list) = &d.intervals {
                out.push((format!("{at}.intervals"), list.as_slice()));
            }
            for (name, c) in &d.channels {
                if let Some(list) = &c.intervals {
                    out.push((format!("{at}.channels.{name}.intervals"), list.as_slice()));
                }
            }
        }
    }
    out.retain(|(_, l)| !l.is_empty());
    out
}

/// Refuses rule times that are not boundaries of a metered channel's shortest interval, and a
/// demand interval a metered channel does not have.
pub(crate) fn check_grid(gateway: &Gateway, buses: &[Bus], errs: &mut Errors) {
    let lists = interval_lists(gateway, buses);
    if let Some(cal) = &gateway.tariffs {
        for (at, list) in &lists {
            let shortest = list.iter().min_by_key(|p| p.ms()).expect("not empty");
            let off = cal.off_grid(shortest);
            if !off.is_empty() {
                errs.push(
                    "tariffs.rule",
                    None,
                    format!(
                        "{} not a boundary of the {shortest} intervals of {at}: every interval record must lie in one tariff",
                        off.join(", ") + if off.len() == 1 { " is" } else { " are" },
                    ),
                );
            }
        }
    }
    let Some(demand) = gateway.billing.as_ref().and_then(|b| b.demand.as_ref()) else {
        return;
    };
    for (at, list) in &lists {
        if !list.iter().any(|p| p == demand) {
            errs.push(
                "billing.demand",
                None,
                format!("{demand} is not one of the intervals of {at}: add it there"),
            );
        }
    }
}

#[cfg(test)]
mod tests {
    use std::collections::HashMap;
    use std::path::Path;

    use crate::config::Config;

    const BASE: &str = r#"
[gateway]
id = "edge-01"
state_dir = "/tmp/pg"
timezone = "Europe/Berlin"
intervals = ["15min", "1d"]
[mqtt]
host = "broker"
[buses.line1]
port = "/dev/ttyUSB0"
[buses.line1.devices.meter1]
unit = 3
model = "yl67"
[buses.line1.devices.meter1.channels.a0]
intervals = ["1h"]
"#;

    fn errors(extra: &str) -> Vec<String> {
        let text = format!("{BASE}{extra}");
        match Config::from_toml(&text, Path::new("/etc/p.toml"), Some(HashMap::new())) {
            Ok(_) => Vec::new(),
            Err(e) => {
                e.0.iter()
                    .map(|e| format!("{}: {}", e.path, e.message))
                    .collect()
            }
        }
    }

    #[test]
    fn a_rule_on_every_channels_grid_is_taken_with_its_tariffs_numbered() {
        let text = format!(
            "{BASE}[tariffs]\ndefault = \"offpeak\"\nholidays = [\"2026-12-25\"]\n\
             [[tariffs.rule]]\ntariff = \"peak\"\ndays = [\"mon\", \"fri\"]\nfrom = \"07:00\"\nto = \"21:00\"\n\
             [billing]\nperiod = \"monthly\"\nday = 15\ndemand = \"15min\"\n"
        );
        let text = text.replace("intervals = [\"1h\"]", "intervals = [\"15min\", \"1h\"]");
        let c = Config::from_toml(&text, Path::new("/etc/p.toml"), Some(HashMap::new())).unwrap();
        let cal = c.gateway.tariffs.unwrap();
        assert_eq!(cal.names(), ["offpeak", "peak"]);
        let b = c.gateway.billing.unwrap();
        assert_eq!(
            b.cycle,
            crate::metering::billing::Cycle::Monthly { day: 15 }
        );
    }

    #[test]
    fn a_rule_time_off_a_channels_shortest_interval_is_refused_naming_both() {
        let errs = errors(
            "[tariffs]\ndefault = \"offpeak\"\n[[tariffs.rule]]\ntariff = \"peak\"\n\
             days = [\"mon\"]\nfrom = \"07:30\"\nto = \"21:00\"\n",
        );
        assert_eq!(
            errs,
            [
                "tariffs.rule: 07:30 is not a boundary of the 1h intervals of \
              buses.line1.devices.meter1.channels.a0.intervals: every interval record must lie in one tariff"
            ]
        );
    }

    #[test]
    fn unknown_days_and_a_backwards_rule_are_refused_by_rule_number() {
        let errs = errors(
            "[tariffs]\ndefault = \"offpeak\"\n[[tariffs.rule]]\ntariff = \"peak\"\n\
             days = [\"monday\"]\nfrom = \"21:00\"\nto = \"07:00\"\n",
        );
        assert_eq!(
            errs,
            [
                "tariffs.rule[1]: \"monday\" is not a day: write one of mon, tue, wed, thu, fri, sat, sun",
                "tariffs.rule[1]: runs from 21:00 to 07:00: `to` must be after `from` (\"00:00\" means midnight); a rule across midnight is two rules",
            ]
        );
    }

    #[test]
    fn a_demand_interval_a_channel_lacks_or_that_does_not_divide_an_hour_is_refused() {
        let errs = errors("[billing]\nperiod = \"daily\"\ndemand = \"15min\"\n");
        assert_eq!(
            errs,
            ["billing.demand: 15min is not one of the intervals of \
              buses.line1.devices.meter1.channels.a0.intervals: add it there"]
        );
        let errs = errors("[billing]\nperiod = \"weekly\"\nday = 30\ndemand = \"2h\"\n");
        assert_eq!(
            errs,
            [
                "billing.period: \"weekly\" is not a billing period: \"daily\" or \"monthly\"",
                "billing.demand: \"2h\" does not divide an hour: demand is a mean power per hour",
            ]
        );
    }

    #[test]
    fn a_signing_key_is_read_when_checked_and_a_missing_or_foreign_one_is_refused() {
        let dir = std::env::temp_dir().join(format!("pg-signing-{}", std::process::id()));
        std::fs::create_dir_all(&dir).unwrap();
        let good = dir.join("good.pem");
        use crate::signing::SigningKey;
        std::fs::write(&good, SigningKey::generate_pem().unwrap()).unwrap();
        let bad = dir.join("bad.pem");
        std::fs::write(&bad, "hello").unwrap();
        let with = |file: &Path| {
            format!(
                "{BASE}[billing]\nperiod = \"daily\"\nsigning_key = \"{}\"\n",
                file.display()
            )
        };
        let c = Config::from_toml(&with(&good), Path::new("/etc/p.toml"), Some(HashMap::new()));
        let b = c.unwrap().gateway.billing.unwrap();
        let pem = std::fs::read_to_string(&good).unwrap();
        let want = SigningKey::from_pem(&pem).unwrap();
        assert_eq!(b.signer.as_deref(), Some(&want));
        for (file, says) in [(dir.join("none.pem"), "cannot read"), (bad, "not a PEM")] {
            let errs = errors(&with(&file)[BASE.len()..]);
            assert_eq!(errs.len(), 1, "{errs:?}");
            assert!(errs[0].starts_with("billing.signing_key: "), "{errs:?}");
            assert!(errs[0].contains(says), "{errs:?}");
        }
        let _ = std::fs::remove_dir_all(&dir);
    }
}

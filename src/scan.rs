//! A scan of a bus requested over MQTT (`<root>/bus/<bus>/scan`), as the router checks it and
//! hands it to the bus: protocol-neutral, so the MQTT side never stands on a driver. The bus's
//! driver carries it out in idle line time (Modbus: `modbus/driver/survey.rs`, M-Bus:
//! `mbus/driver/master/survey.rs`), each keeping its progress in a [`Survey`]. Pure.

use std::time::Duration;

use serde_json::Value;
use tokio::time::Instant;

use crate::command::Reply;
use crate::outcome::{Found, ScanOutcome, ScanProgress, ScanReport};

/// A checked scan request, on its way to a bus.
#[derive(Debug, Clone)]
pub struct ScanRequest {
    pub units: Vec<u8>,
    pub id: Option<String>,
    pub reply: Reply,
    /// Where each module found is reported as it answers (`<request topic>/progress`).
    pub progress: String,
}

/// The payload: empty, or `{"units": "1-247", "id": "..."}` and nothing else.
pub fn parse_scan_payload(payload: &[u8]) -> Result<(Vec<u8>, Option<String>), String> {
    if payload.iter().all(u8::is_ascii_whitespace) {
        return Ok((parse_units("1-247").map_err(|e| e.to_string())?, None));
    }
    if payload.len() > 1024 {
        return Err("payload longer than 1024 bytes".into());
    }
    let v: Value = serde_json::from_slice(payload).map_err(|e| format!("not JSON: {e}"))?;
    let obj = v.as_object().ok_or("payload is not a JSON object")?;
    if let Some(k) = obj.keys().find(|k| !matches!(k.as_str(), "units" | "id")) {
        return Err(format!("unknown key {k:?}: use \"units\" and \"id\""));
    }
    let id = match obj.get("id") {
        None => None,
        Some(Value::String(s)) if s.len() <= 64 => Some(s.clone()),
        Some(_) => return Err("\"id\" must be a string of at most 64 characters".into()),
    };
    let units = match obj.get("units") {
        None => "1-247",
        Some(Value::String(s)) => s.as_str(),
        Some(_) => return Err("\"units\" must be a string such as \"1-247\"".into()),
    };
    Ok((parse_units(units).map_err(|e| e.to_string())?, id))
}

/// Unit ids from "1-247", "5" or "1,3,10-20"; 0 and 248.. are refused (Modbus's range, the
/// one protocol that scans today).
pub fn parse_units(text: &str) -> Result<Vec<u8>, String> {
    let bad = |why: String| format!("--units {text:?}: {why}");
    let mut out = Vec::new();
    for part in text.split(',') {
        let part = part.trim();
        let (lo, hi) = part.split_once('-').unwrap_or((part, part));
        let parse = |s: &str| {
            s.trim()
                .parse::<u16>()
                .map_err(|_| bad(format!("{s:?} is not a unit id")))
        };
        let (lo, hi) = (parse(lo)?, parse(hi)?);
        if lo == 0 || hi > 247 {
            return Err(bad("unit ids are 1..=247".into()));
        }
        if lo > hi {
            return Err(bad(format!("{lo}-{hi} runs backwards")));
        }
        out.extend((lo..=hi).map(|u| u as u8));
    }
    out.sort_unstable();
    out.dedup();
    Ok(out)
}

/// How long a scan may take before it reports what it has (a line with no idle time).
pub const SCAN_LIMIT: Duration = Duration::from_secs(600);

/// A scan under way. Pure: the bus asks it for the next unit and records the answer.
#[derive(Debug)]
pub struct Survey {
    request: ScanRequest,
    pending: Vec<u8>,
    configured: Vec<u8>,
    found: Vec<Found>,
    asked: usize,
    started: Instant,
}

impl Survey {
    /// A scan of the requested units except `configured` ones.
    pub fn new(request: ScanRequest, configured: &[u8], now: Instant) -> Survey {
        let pending: Vec<u8> = request
            .units
            .iter()
            .rev()
            .copied()
            .filter(|u| !configured.contains(u))
            .collect();
        let mut configured: Vec<u8> = configured
            .iter()
            .copied()
            .filter(|u| request.units.contains(u))
            .collect();
        configured.sort_unstable();
        Survey {
            configured,
            request,
            pending,
            found: Vec::new(),
            asked: 0,
            started: now,
        }
    }

    /// The unit to ask next.
    pub fn next_unit(&self) -> Option<u8> {
        self.pending.last().copied()
    }

    /// The answer of the unit [`Survey::next_unit`] gave (`None`: silent); a module found is
    /// reported at once (the progress message).
    pub fn record(
        &mut self,
        found: Option<Found>,
        bus: &str,
        now: Instant,
    ) -> Option<ScanProgress> {
        self.pending.pop();
        self.asked += 1;
        let found = found?;
        self.found.push(found.clone());
        Some(ScanProgress {
            bus: bus.to_string(),
            id: self.request.id.clone(),
            found,
            asked: self.asked,
            pending: self.pending.len(),
            elapsed_ms: (now - self.started).as_millis() as u64,
        })
    }

    /// Done, or out of time.
    pub fn finished(&self, now: Instant) -> bool {
        self.pending.is_empty() || now - self.started >= SCAN_LIMIT
    }

    /// The report.
    pub fn result(&self, bus: &str, now: Instant) -> ScanOutcome {
        ScanOutcome::Report(ScanReport {
            bus: bus.to_string(),
            found: self.found.clone(),
            configured: self.configured.clone(),
            asked: self.asked,
            complete: self.pending.is_empty(),
            elapsed_ms: (now - self.started).as_millis() as u64,
            id: self.request.id.clone(),
        })
    }

    pub fn reply(&self) -> &Reply {
        &self.request.reply
    }

    /// Where each device found is reported as it answers.
    pub fn progress_topic(&self) -> &str {
        &self.request.progress
    }

    /// How many devices were found so far.
    pub fn found_count(&self) -> usize {
        self.found.len()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_payload_gives_units_and_id_and_nothing_else() {
        assert_eq!(parse_scan_payload(b"").unwrap().0.len(), 247);
        let (units, id) = parse_scan_payload(br#"{"units":"5-7","id":"a"}"#).unwrap();
        assert_eq!((units, id.as_deref()), (vec![5, 6, 7], Some("a")));
        for bad in [
            &br#"{"units":"0-7"}"#[..],
            br#"{"unit":"5"}"#,
            br#"[1]"#,
            b"scan",
            br#"{"units":5}"#,
        ] {
            assert!(
                parse_scan_payload(bad).is_err(),
                "{}",
                String::from_utf8_lossy(bad)
            );
        }
    }

    #[test]
    fn unit_lists_and_ranges_are_read_and_bad_ones_refused() {
        assert_eq!(parse_units("1-3,7,2").unwrap(), [1, 2, 3, 7]);
        assert_eq!(parse_units("1-247").unwrap().len(), 247);
        for bad in ["0-5", "1-248", "5-1", "x", ""] {
            assert!(parse_units(bad).is_err(), "{bad}");
        }
    }
}

#[cfg(test)]
mod survey_tests {
    use super::*;
    use crate::outcome::Outcome;

    #[test]
    fn configured_units_are_not_asked_and_the_result_lists_them() {
        let req = ScanRequest {
            units: vec![1, 2, 3, 4],
            id: Some("x".into()),
            reply: Reply::default(),
            progress: "pg/bus/line1/scan/progress".into(),
        };
        let t = Instant::now();
        let mut s = Survey::new(req, &[2, 9], t);
        let mut asked = Vec::new();
        while let Some(u) = s.next_unit() {
            asked.push(u);
            assert_eq!(
                s.record(None, "line1", t),
                None,
                "a silent unit is no progress"
            );
        }
        assert_eq!(asked, [1, 3, 4]);
        let r = Outcome::Scan(s.result("line1", t)).to_json();
        use serde_json::json;
        assert_eq!(
            (
                r["configured"].clone(),
                r["complete"].clone(),
                r["id"].clone()
            ),
            (json!([2]), json!(true), json!("x"))
        );
    }

    #[test]
    fn a_module_found_is_reported_at_once_with_the_scan_id_and_again_in_the_result() {
        let req = ScanRequest {
            units: vec![4, 5, 6],
            id: Some("survey-1".into()),
            reply: Reply::default(),
            progress: "pg/bus/line1/scan/progress".into(),
        };
        let t = Instant::now();
        use serde_json::json;
        let mut s = Survey::new(req, &[], t);
        assert_eq!(s.record(None, "line1", t), None);
        let found = Found {
            baud: Some(9600),
            unit: 5,
            model: Some("wj157".into()),
            modes: vec![0],
            channels: vec!["enc0".into()],
            note: None,
            meter: None,
        };
        let progress = s
            .record(
                Some(found.clone()),
                "line1",
                t + Duration::from_millis(1500),
            )
            .expect("reported");
        let v = serde_json::to_value(&progress).unwrap();
        assert_eq!(
            v,
            json!({"bus": "line1", "id": "survey-1", "found": found, "asked": 2, "pending": 1,
                   "elapsed_ms": 1500})
        );
        s.record(None, "line1", t);
        let result = Outcome::Scan(s.result("line1", t)).to_json();
        assert_eq!(result["found"], json!([found]));
    }
}

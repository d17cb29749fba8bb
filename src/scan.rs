//! A scan of a bus requested over MQTT (`<root>/bus/<bus>/scan`), as the router checks it and
//! hands it to the bus: protocol-neutral, so the MQTT side never stands on a driver. The bus's
//! driver carries it out in idle line time (Modbus: `driver/modbus/survey.rs`). Pure.

use serde_json::Value;

use crate::command::Reply;

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

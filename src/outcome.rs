//! The answers the gateway gives to commands and scans, as types until a format writes them:
//! metrics and priorities read the type, never the text (a scan's report has no `ok` key, and
//! once counted as a refusal for it). Pure.

use serde::Serialize;

use crate::command::{self, CommandError};

/// A unit that answered a scan.
#[derive(Debug, Clone, PartialEq, serde::Serialize)]
pub struct Found {
    /// The baud rate it answered at (`None` on Modbus TCP).
    pub baud: Option<u32>,
    pub unit: u8,
    /// Its model, when a profile's identification matched.
    pub model: Option<String>,
    /// Raw work-mode registers, in the profile's order.
    pub modes: Vec<u16>,
    /// Its channels in those work modes.
    pub channels: Vec<String>,
    /// Anything worth knowing (unknown model, modes not readable).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub note: Option<String>,
    /// An M-Bus meter's secondary address (`unit` is then its primary address).
    #[serde(skip_serializing_if = "Option::is_none")]
    pub meter: Option<MeterFound>,
}

/// Who an M-Bus meter a scan found is: its secondary address.
#[derive(Debug, Clone, PartialEq, Eq, serde::Serialize)]
pub struct MeterFound {
    /// The 8-digit identification number.
    pub id: String,
    /// Three letters.
    pub manufacturer: String,
    pub version: u8,
    pub medium: u8,
    /// The medium's name by the standard's table.
    pub medium_name: String,
}

/// A module the scan found, reported as it answers (the result lists it again).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScanProgress {
    pub bus: String,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<String>,
    pub found: Found,
    /// Units asked so far, and still to ask.
    pub asked: usize,
    pub pending: usize,
    pub elapsed_ms: u64,
}

/// The answer to a command or a scan.
#[derive(Debug, Clone, PartialEq)]
pub enum Outcome {
    Command(CommandOutcome),
    Scan(ScanOutcome),
    /// A config pushed from the broker (`<root>/config/result`).
    Config(ConfigOutcome),
}

/// What became of a pushed config: shaped as command results are (`ok`, `error`, `message`),
/// with its `id` and where it stands.
#[derive(Debug, Clone, PartialEq)]
pub struct ConfigOutcome {
    pub id: Option<String>,
    /// `applied` (in force, watched: a progress result), `kept` (the grace period passed),
    /// `rolled_back`, or `refused`.
    pub status: &'static str,
    /// The error code when it is not in force: `bad_payload`, `bad_config`, `forbidden`,
    /// `busy`, `write_failed`, `rolled_back`.
    pub error: Option<&'static str>,
    pub message: String,
    /// The hash of the config in force after this step.
    pub hash: Option<String>,
}

/// What became of a clear, preset or clear_all.
#[derive(Debug, Clone, PartialEq)]
pub struct CommandOutcome {
    /// The request's `id`, if it had one.
    pub id: Option<String>,
    /// The operation, once the payload named one.
    pub op: Option<String>,
    /// Done (with the count read back, where there is one), or why not.
    pub result: Result<Option<i64>, CommandError>,
}

/// What became of a scan request.
#[derive(Debug, Clone, PartialEq)]
pub enum ScanOutcome {
    /// The scan ran (to its end or its time limit): what it found.
    Report(ScanReport),
    /// The scan was refused before it asked any unit.
    Refused {
        bus: String,
        id: Option<String>,
        /// Machine-readable: `busy`, `too_large`, `bad_request`, …
        code: &'static str,
        message: String,
    },
}

/// A scan's findings.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct ScanReport {
    pub bus: String,
    pub found: Vec<Found>,
    /// Units of configured devices in the requested range (not asked).
    pub configured: Vec<u8>,
    pub asked: usize,
    /// Every requested unit was asked (not cut short by the time limit).
    pub complete: bool,
    pub elapsed_ms: u64,
    #[serde(skip_serializing_if = "Option::is_none")]
    pub id: Option<String>,
}

impl Outcome {
    /// The refusal's code when the request was refused or failed; `None` when it succeeded.
    pub fn refusal(&self) -> Option<&str> {
        match self {
            Outcome::Command(c) => c.result.as_ref().err().map(CommandError::code),
            Outcome::Scan(ScanOutcome::Refused { code, .. }) => Some(code),
            Outcome::Scan(ScanOutcome::Report(_)) => None,
            Outcome::Config(c) => c.error,
        }
    }

    /// The result as JSON text (the JSON format's payload).
    pub fn to_json(&self) -> serde_json::Value {
        match self {
            Outcome::Command(c) => {
                command::result_json(c.id.as_deref(), c.op.as_deref(), &c.result)
            }
            Outcome::Scan(ScanOutcome::Report(r)) => {
                serde_json::to_value(r).unwrap_or(serde_json::Value::Null)
            }
            Outcome::Config(c) => {
                let mut v = serde_json::json!({
                    "ok": c.error.is_none(),
                    "status": c.status,
                    "message": c.message,
                });
                if let Some(e) = c.error {
                    v["error"] = serde_json::json!(e);
                }
                if let Some(id) = &c.id {
                    v["id"] = serde_json::json!(id);
                }
                if let Some(h) = &c.hash {
                    v["config"] = serde_json::json!(h);
                }
                v
            }
            Outcome::Scan(ScanOutcome::Refused {
                bus,
                id,
                code,
                message,
            }) => {
                let mut v = serde_json::json!({"bus": bus, "error": code, "message": message});
                if let Some(id) = id {
                    v["id"] = serde_json::json!(id);
                }
                v
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn report() -> Outcome {
        Outcome::Scan(ScanOutcome::Report(ScanReport {
            bus: "line1".into(),
            found: Vec::new(),
            configured: vec![1],
            asked: 246,
            complete: true,
            elapsed_ms: 1200,
            id: Some("s1".into()),
        }))
    }

    #[test]
    fn a_scan_report_is_no_refusal_though_it_has_no_ok_key() {
        let r = report();
        assert_eq!(r.refusal(), None);
        assert!(r.to_json().get("ok").is_none());
        assert_eq!(r.to_json()["id"], "s1");
    }

    #[test]
    fn a_refused_command_or_scan_names_its_code() {
        let c = Outcome::Command(CommandOutcome {
            id: None,
            op: Some("clear".into()),
            result: Err(CommandError::UnknownDevice("nosuch".into())),
        });
        assert_eq!(c.refusal(), Some("unknown_device"));
        assert_eq!(c.to_json()["ok"], false);
        let s = Outcome::Scan(ScanOutcome::Refused {
            bus: "l".into(),
            id: None,
            code: "busy",
            message: "a scan of this bus is under way".into(),
        });
        assert_eq!(s.refusal(), Some("busy"));
    }
}

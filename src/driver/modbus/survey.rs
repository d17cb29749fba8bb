//! A bus scan requested over MQTT (`<root>/bus/<bus>/scan`), carried out by the running bus in
//! its idle line time: one unit is asked only when the next poll is due later than the longest
//! the question can take, so configured devices keep their poll rate. Units of configured
//! devices are not asked. One scan per bus at a time; each module found is reported on
//! `<root>/bus/<bus>/scan/progress` as it answers (a scan of a busy line takes minutes), and the
//! result goes to `<root>/bus/<bus>/scan/result` (and the MQTT v5 response topic).

use std::time::Duration;

use tokio::sync::mpsc::Receiver;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::link::Link;
use super::probe::describe;
use crate::command::Reply;
use crate::outcome::{Found, ScanProgress};
use crate::outcome::{Outcome, ScanOutcome, ScanReport};
use crate::profile::Profiles;
use crate::reading::Output;
use crate::scan::ScanRequest;

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
}

/// The bus's side: takes new requests (one at a time; others are answered "busy") and, when the
/// line is idle until `next_due`, asks one unit. Returns whether it used the line.
#[allow(clippy::too_many_arguments)] // the bus loop's state, lent for one step
pub async fn idle_step(
    survey: &mut Option<Survey>,
    requests: &mut Option<Receiver<ScanRequest>>,
    link: &mut Link,
    next_due: Instant,
    configured: &[u8],
    bus: &str,
    out: &tokio::sync::mpsc::UnboundedSender<Output>,
    shutdown: &CancellationToken,
) -> bool {
    if let Some(rx) = requests.as_mut() {
        while let Ok(req) = rx.try_recv() {
            if survey.is_some() {
                let busy = ScanOutcome::Refused {
                    bus: bus.to_string(),
                    id: req.id.clone(),
                    code: "busy",
                    message: "a scan of this bus is under way".into(),
                };
                send(out, &req.reply, busy);
            } else {
                tracing::info!(
                    bus,
                    units = req.units.len(),
                    "scan requested; asking units in idle line time"
                );
                *survey = Some(Survey::new(req, configured, Instant::now()));
            }
        }
    }
    let Some(s) = survey.as_mut() else {
        return false;
    };
    let profiles = Profiles::builtin();
    let answer = super::probe::answer_time(&profiles);
    let timeout = link.timeout_for(answer, 3);
    let cost = timeout
        + link
            .timing()
            .map(|t| t.silent_interval() * 2)
            .unwrap_or_default();
    let now = Instant::now();
    let mut used = false;
    if let Some(unit) = s.next_unit()
        && next_due.saturating_duration_since(now) >= cost
        && !shutdown.is_cancelled()
    {
        used = true;
        let found = match super::probe::identify(link, &profiles, unit, timeout, false).await {
            Ok(Some(identified)) => {
                let baud = link.timing().map(|t| t.baud);
                let mut f = describe(link, baud, unit, identified, timeout, Some(next_due)).await;
                f.baud = baud;
                Some(f)
            }
            _ => None,
        };
        if let Some(progress) = s.record(found, bus, Instant::now()) {
            tracing::info!(bus, unit = progress.found.unit, "scan found a module");
            let _ = out.send(Output::ScanProgress {
                topic: s.request.progress.clone(),
                progress: Box::new(progress),
            });
        }
    }
    let now = Instant::now();
    if s.finished(now) {
        let result = s.result(bus, now);
        tracing::info!(bus, found = s.found.len(), "scan finished");
        send(out, s.reply(), result);
        *survey = None;
    }
    used
}

fn send(out: &tokio::sync::mpsc::UnboundedSender<Output>, reply: &Reply, outcome: ScanOutcome) {
    let _ = out.send(Output::CommandResult {
        reply: reply.clone(),
        outcome: Outcome::Scan(outcome),
    });
}

#[cfg(test)]
mod tests {
    use super::*;

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

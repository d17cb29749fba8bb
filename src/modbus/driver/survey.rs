//! A bus scan requested over MQTT (`<root>/bus/<bus>/scan`), carried out by the running bus in
//! its idle line time: one unit is asked only when the next poll is due later than the longest
//! the question can take, so configured devices keep their poll rate. Units of configured
//! devices are not asked. One scan per bus at a time; each module found is reported on
//! `<root>/bus/<bus>/scan/progress` as it answers (a scan of a busy line takes minutes), and the
//! result goes to `<root>/bus/<bus>/scan/result` (and the MQTT v5 response topic).

use tokio::sync::mpsc::Receiver;
use tokio::time::Instant;
use tokio_util::sync::CancellationToken;

use super::link::Link;
use super::probe::describe;
use crate::command::Reply;
use crate::outcome::{Outcome, ScanOutcome};
use crate::profile::Profiles;
use crate::reading::Output;
use crate::scan::{ScanRequest, Survey};

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
    take_requests(survey, requests, configured, bus, out);
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
                topic: s.progress_topic().to_string(),
                progress: Box::new(progress),
            });
        }
    }
    let now = Instant::now();
    if s.finished(now) {
        let result = s.result(bus, now);
        tracing::info!(bus, found = s.found_count(), "scan finished");
        send(out, s.reply(), result);
        *survey = None;
    }
    used
}

/// New scan requests: the first starts a survey, any while one runs is answered "busy".
fn take_requests(
    survey: &mut Option<Survey>,
    requests: &mut Option<Receiver<ScanRequest>>,
    configured: &[u8],
    bus: &str,
    out: &tokio::sync::mpsc::UnboundedSender<Output>,
) {
    let Some(rx) = requests.as_mut() else { return };
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

fn send(out: &tokio::sync::mpsc::UnboundedSender<Output>, reply: &Reply, outcome: ScanOutcome) {
    let _ = out.send(Output::CommandResult {
        reply: reply.clone(),
        outcome: Outcome::Scan(outcome),
    });
}

//! An output of kind `modbus`: the gateway's totals, rates and states as registers of a Modbus
//! TCP server, for the PLCs, HMIs and SCADA that poll (docs/plc.md). It is not an MQTT
//! connection: it takes the same events as every output (its own channel from the fan-out), keeps
//! the register image ([`image`]) and answers requests from it ([`answer`]) on tokio-modbus's
//! server ([`server`]). Writes of command registers, when `commands = true`, go to the command
//! router as a command on the channel's command topic would (the same admission), and the write
//! is answered when the command is.

pub mod answer;
pub mod image;
pub mod listener;
pub mod metrics;

use std::collections::HashMap;
use std::future::Future;
use std::pin::Pin;
use std::sync::atomic::{AtomicU64, Ordering};
use std::sync::{Arc, Mutex, RwLock};
use std::time::{Duration, SystemTime};

use tokio::sync::mpsc::{Sender, UnboundedReceiver};
use tokio::sync::oneshot;
use tokio_modbus::{ExceptionCode, Response, SlaveRequest};

use crate::config::Config;
use crate::dispatch::Incoming;
use crate::health::Heart;
use crate::metrics::OutputMetrics;
use crate::modbus::config::server::ModbusServer;
use crate::modbus::config::server::map::{RegisterMap, result};
use crate::outcome::Outcome;
use crate::reading::Output;
use answer::{Asked, Command, Op};
use image::Image;

/// How long a write waits for its command's answer.
pub const COMMAND_WAIT: Duration = Duration::from_secs(10);

/// A Modbus server output ready to run.
pub struct Task {
    pub server: ModbusServer,
    pub map: RegisterMap,
    /// The gateway's topic root: a write becomes a command on its topics.
    pub root: String,
    pub heart: Heart,
    pub metrics: OutputMetrics,
}

/// What the listener's connections share with the output's loop.
struct Shared {
    image: RwLock<Image>,
    pending: Mutex<HashMap<String, oneshot::Sender<Outcome>>>,
    next: AtomicU64,
    started_ms: u64,
    server: ModbusServer,
    topics: crate::topics::Topics,
    incoming: Sender<Incoming>,
    metrics: OutputMetrics,
}

fn read<T>(l: &RwLock<T>) -> std::sync::RwLockReadGuard<'_, T> {
    l.read().unwrap_or_else(|e| e.into_inner())
}

fn write<T>(l: &RwLock<T>) -> std::sync::RwLockWriteGuard<'_, T> {
    l.write().unwrap_or_else(|e| e.into_inner())
}

fn pending(s: &Shared) -> std::sync::MutexGuard<'_, HashMap<String, oneshot::Sender<Outcome>>> {
    s.pending.lock().unwrap_or_else(|e| e.into_inner())
}

/// Serves until the fan-out closes `events` (the gateway stops, or a new config rebuilt the
/// outputs): the listener and every connection end with it.
/// The Modbus server outputs of `config`.
pub fn servers(
    config: &Config,
    parts: impl Fn(&str) -> (Heart, OutputMetrics),
) -> Vec<Box<dyn crate::publish::server::Server>> {
    let map = RegisterMap::of(config);
    let each = config.outputs.servers.modbus.iter().map(|server| {
        let (heart, metrics) = parts(&server.name);
        let task = Task {
            server: server.clone(),
            map: map.clone(),
            root: config.mqtt.topic_root.clone(),
            heart,
            metrics,
        };
        Box::new(task) as Box<dyn crate::publish::server::Server>
    });
    each.collect()
}

impl crate::publish::server::Server for Task {
    fn name(&self) -> &str {
        &self.server.name
    }

    fn start(
        self: Box<Self>,
        events: UnboundedReceiver<Output>,
        incoming: Sender<Incoming>,
        reloads: UnboundedReceiver<Config>,
    ) -> tokio::task::JoinHandle<()> {
        tokio::spawn(run(*self, events, incoming, reloads))
    }
}

pub async fn run(
    task: Task,
    mut events: UnboundedReceiver<Output>,
    incoming: Sender<Incoming>,
    mut reloads: UnboundedReceiver<Config>,
) {
    let Task {
        server,
        map,
        root,
        heart,
        metrics,
    } = task;
    let listener = match tokio::net::TcpListener::bind(server.listen).await {
        Ok(l) => l,
        Err(e) => {
            let why = format!("cannot listen on {}: {e}", server.listen);
            tracing::error!(output = %server.name, "{why}; the Modbus server does not run");
            heart.set_up(false);
            heart.set_problem(Some(why));
            while events.recv().await.is_some() {}
            return;
        }
    };
    tracing::info!(output = %server.name, listen = %server.listen, units = map.units.len(), commands = server.commands, "Modbus server listening");
    let shared = Arc::new(Shared {
        image: RwLock::new(Image::new(&map)),
        pending: Mutex::default(),
        next: AtomicU64::new(0),
        started_ms: crate::reading::unix_ms(SystemTime::now()),
        topics: crate::topics::Topics::new(&root),
        server,
        incoming,
        metrics,
    });
    heart.set_up(true);
    let serving = tokio::spawn(serve(listener, shared.clone()));
    let mut beat = tokio::time::interval(Duration::from_secs(1));
    loop {
        tokio::select! {
            event = events.recv() => match event {
                Some(event) => shared.event(event),
                None => break,
            },
            Some(config) = reloads.recv() => {
                let map = RegisterMap::of(&config);
                let next = read(&shared.image).remap(&map);
                *write(&shared.image) = next;
            }
            _ = beat.tick() => heart.beat(),
        }
    }
    // The listener is closed when the aborted task is dropped, which abort only asks for: a
    // rebuilt output binds the same port as soon as this returns.
    serving.abort();
    let _ = serving.await;
    heart.set_up(false);
}

/// Accepts until aborted; dropping the server closes every connection it serves.
async fn serve(listener: tokio::net::TcpListener, shared: Arc<Shared>) {
    let slots = Arc::new(Mutex::new(listener::Slots::default()));
    let server = tokio_modbus::server::tcp::Server::new(listener);
    let on_connected = |stream, peer| {
        let leased = listener::admit(&shared.server, &slots, &shared.metrics, stream, peer);
        let service = Service(shared.clone());
        std::future::ready(Ok(leased.map(|l| (service, l))))
    };
    let metrics = shared.metrics.clone();
    let on_error = move |e: std::io::Error| {
        if e.kind() == std::io::ErrorKind::InvalidData {
            metrics.server_closed("bad_frame");
        }
        tracing::debug!("a Modbus connection ended: {e}");
    };
    let name = shared.server.name.as_str();
    // A flood beyond the file descriptors fails an accept every ACCEPT_PAUSE or so.
    let mut budget = crate::log_budget::LogBudget::new(3);
    keep_serving(
        || server.serve(&on_connected, on_error.clone()),
        |e| {
            let (log, before) = budget.allow(tokio::time::Instant::now());
            if let Some(n) = before {
                tracing::warn!(output = %name, "{n} more failed accepts in the last minute");
            }
            if log {
                tracing::error!(output = %name, "the Modbus server could not accept a connection ({e}): it closes those it holds and listens again in {ACCEPT_PAUSE:?}");
            }
        },
    )
    .await;
}

/// How long after a failed accept the server listens again.
pub const ACCEPT_PAUSE: Duration = Duration::from_millis(500);

/// Runs `serve` again `ACCEPT_PAUSE` after each error it ends with. tokio-modbus's accept loop
/// ends at the first accept that fails (the process out of file descriptors, a flood of
/// connections beyond them) and closes the connections it serves as it ends; without this the
/// listener would be gone for good while the rest of the gateway runs on.
async fn keep_serving<F, S>(mut serve: F, mut failed: impl FnMut(&std::io::Error))
where
    F: FnMut() -> S,
    S: Future<Output = std::io::Result<()>>,
{
    while let Err(e) = serve().await {
        failed(&e);
        tokio::time::sleep(ACCEPT_PAUSE).await;
    }
}

impl Shared {
    /// An event from the fan-out: the image, or the answer to a write.
    fn event(&self, event: Output) {
        match event {
            Output::CommandResult { reply, outcome } => {
                let ours = reply
                    .via
                    .as_ref()
                    .is_some_and(|v| *v.output == *self.server.name);
                let id = match &outcome {
                    Outcome::Command(c) => c.id.clone(),
                    _ => None,
                };
                if let (true, Some(id)) = (ours, id)
                    && let Some(tx) = pending(self).remove(&id)
                {
                    let _ = tx.send(outcome);
                }
            }
            // Nothing owed is held here: a dropped checkpoint counts as durable.
            Output::Checkpoint(_) => {}
            event => {
                if matches!(
                    event,
                    Output::DeviceReadings { .. }
                        | Output::DeviceStatus { .. }
                        | Output::DeviceProblem { .. }
                ) {
                    write(&self.image).apply(&event);
                }
            }
        }
    }

    /// A write of a command register: the command to the router, the write answered with it.
    async fn command(self: Arc<Self>, c: Command) -> Result<Response, ExceptionCode> {
        let n = self.next.fetch_add(1, Ordering::Relaxed);
        let id = format!("modbus-{}-{}-{n}", self.server.name, self.started_ms);
        let payload = match c.op {
            Op::Clear => serde_json::json!({"op": "clear", "id": id}),
            Op::Preset(v) => serde_json::json!({"op": "preset", "value": v, "id": id}),
        };
        let (tx, rx) = oneshot::channel();
        pending(&self).insert(id.clone(), tx);
        write(&self.image).command(c.unit, c.base, result::PENDING);
        let msg = Incoming {
            topic: self.topics.channel_command(&c.device, &c.channel),
            payload: payload.to_string().into(),
            retain: false,
            response_topic: None,
            correlation: None,
            via: Some(crate::command::Via {
                output: self.server.name.as_str().into(),
                wrote: None,
            }),
        };
        if self.incoming.try_send(msg).is_err() {
            pending(&self).remove(&id);
            write(&self.image).command(c.unit, c.base, result::FAILED);
            return Err(ExceptionCode::ServerDeviceBusy);
        }
        let outcome = tokio::time::timeout(COMMAND_WAIT, rx).await;
        pending(&self).remove(&id);
        let Ok(Ok(outcome)) = outcome else {
            write(&self.image).command(c.unit, c.base, result::FAILED);
            return Err(ExceptionCode::GatewayTargetDevice);
        };
        let code = image::result_code(&outcome);
        write(&self.image).command(c.unit, c.base, code);
        if code == result::DONE {
            Ok(c.done)
        } else {
            Err(ExceptionCode::ServerDeviceFailure)
        }
    }
}

/// The service of one connection: every request answered from the image.
#[derive(Clone)]
struct Service(Arc<Shared>);

type Answer = Pin<Box<dyn Future<Output = Result<Response, ExceptionCode>> + Send>>;

impl tokio_modbus::server::Service for Service {
    type Request = SlaveRequest<'static>;
    type Response = Response;
    type Exception = ExceptionCode;
    type Future = Answer;

    fn call(&self, req: SlaveRequest<'static>) -> Answer {
        let shared = &self.0;
        let function = req.request.function_code().value();
        let asked = answer::answer(
            &read(&shared.image),
            shared.server.commands,
            req.slave,
            &req.request,
            SystemTime::now(),
        );
        let metrics = shared.metrics.clone();
        match asked {
            Ok(Asked::Answer(r)) => {
                metrics.server_request(function, "ok");
                Box::pin(std::future::ready(Ok(r)))
            }
            Err(e) => {
                metrics.server_request(function, answer::exception_name(e));
                Box::pin(std::future::ready(Err(e)))
            }
            Ok(Asked::Command(c)) => {
                let shared = shared.clone();
                Box::pin(async move {
                    let r = shared.command(c).await;
                    let name = r
                        .as_ref()
                        .err()
                        .map_or("ok", |e| answer::exception_name(*e));
                    metrics.server_request(function, name);
                    r
                })
            }
        }
    }
}

#[cfg(test)]
mod tests;

#[cfg(test)]
mod accept_tests {
    use super::*;

    #[tokio::test(start_paused = true)]
    async fn an_accept_loop_that_ended_on_an_error_listens_again_after_a_pause() {
        let mut ends = vec![
            Err(std::io::Error::from_raw_os_error(24)),
            Err(std::io::Error::from_raw_os_error(24)),
            Ok(()),
        ]
        .into_iter();
        let mut runs = 0;
        let mut failures = Vec::new();
        let started = tokio::time::Instant::now();
        keep_serving(
            || {
                runs += 1;
                std::future::ready(ends.next().expect("asked at most three times"))
            },
            |e| failures.push(e.raw_os_error()),
        )
        .await;
        assert_eq!(runs, 3, "served again after each failure");
        assert_eq!(failures, [Some(24), Some(24)]);
        assert_eq!(started.elapsed(), 2 * ACCEPT_PAUSE, "a pause between runs");
    }
}

//! The Modbus server shell around the simulated modules.

use std::future::ready;
use std::io;
use std::net::SocketAddr;
use std::path::PathBuf;
use std::time::Instant;

use serialport::{SerialPort, TTYPort};
use tokio_modbus::server::Service;
use tokio_modbus::{ExceptionCode, Request, Response, SlaveRequest};
use tokio_serial::SerialStream;
use tokio_util::sync::CancellationToken;

use super::model::SimModule;

/// The modules of one simulated bus, by unit id.
pub type Modules = std::sync::Arc<std::sync::Mutex<std::collections::BTreeMap<u8, SimModule>>>;

/// Answers requests for the modules of one bus; absent or silent units stay silent.
#[derive(Clone)]
pub struct SimService {
    modules: Modules,
    start: Instant,
    /// The gateway's end of the pseudo-terminal, to read the speed it set (see `comm`).
    speed: Option<std::sync::Arc<std::sync::Mutex<TTYPort>>>,
}

impl SimService {
    pub fn new(modules: Modules, start: Instant) -> SimService {
        SimService {
            modules,
            start,
            speed: None,
        }
    }

    /// The baud rate the line is set to now, where the service can see it.
    fn line_speed(&self) -> Option<u32> {
        let port = self.speed.as_ref()?;
        port.lock()
            .unwrap_or_else(|e| e.into_inner())
            .baud_rate()
            .ok()
    }

    /// The answer and how long the module takes to give it.
    fn answer(
        &self,
        req: SlaveRequest<'static>,
    ) -> (Result<Option<Response>, ExceptionCode>, std::time::Duration) {
        let delay = self
            .modules
            .lock()
            .unwrap_or_else(|e| e.into_inner())
            .get(&req.slave)
            .map(|m| m.answer_delay)
            .unwrap_or_default();
        (self.answer_now(req), delay)
    }

    fn answer_now(&self, req: SlaveRequest<'static>) -> Result<Option<Response>, ExceptionCode> {
        let now = self.start.elapsed().as_secs_f64();
        let mut modules = self.modules.lock().unwrap_or_else(|e| e.into_inner());
        let Some(m) = modules.get_mut(&req.slave) else {
            return Ok(None);
        };
        if m.silent
            || m.baud
                .is_some_and(|own| self.line_speed().is_some_and(|b| b != own))
        {
            return Ok(None);
        }
        if m.nonsense {
            m.writes += u64::from(matches!(
                req.request,
                Request::WriteSingleRegister(..) | Request::WriteMultipleRegisters(..)
            ));
            return nonsense(&req.request, m.writes.wrapping_add(now.to_bits()));
        }
        let response = match req.request {
            Request::ReadHoldingRegisters(start, len) => match m.read(now, start, len) {
                Ok(words) => {
                    m.reads += 1;
                    m.note_answer(now, start, len);
                    Response::ReadHoldingRegisters(words)
                }
                Err(ExceptionCode::IllegalDataAddress) if m.silent_on_unknown => return Ok(None),
                r => Response::ReadHoldingRegisters(r?),
            },
            Request::WriteSingleRegister(a, v) => {
                m.writes += 1;
                m.last_write.get_or_insert(now);
                m.write_one(now, a, v)?;
                super::comm::after_write(&mut modules, req.slave);
                Response::WriteSingleRegister(a, v)
            }
            Request::WriteMultipleRegisters(a, values) => {
                m.writes += 1;
                m.last_write.get_or_insert(now);
                m.write_many(now, a, &values)?;
                super::comm::after_write(&mut modules, req.slave);
                Response::WriteMultipleRegisters(a, values.len() as u16)
            }
            _ => return Err(ExceptionCode::IllegalFunction),
        };
        Ok(Some(response))
    }
}

/// A well-framed answer that does not fit `req`.
fn nonsense(req: &Request<'_>, salt: u64) -> Result<Option<Response>, ExceptionCode> {
    let len = match req {
        Request::ReadHoldingRegisters(_, n) => usize::from(*n),
        _ => 1,
    };
    match salt % 4 {
        0 => Ok(Some(Response::ReadHoldingRegisters(vec![0xDEAD; len + 1]))),
        1 => Ok(Some(Response::ReadHoldingRegisters(
            vec![0xBEEF; len.saturating_sub(1)],
        ))),
        2 => Ok(Some(Response::WriteSingleRegister(0xFFFF, 0x1234))),
        _ => Err(ExceptionCode::Custom(0x40 + (salt % 32) as u8)),
    }
}

impl Service for SimService {
    type Request = SlaveRequest<'static>;
    type Response = Option<Response>;
    type Exception = ExceptionCode;
    type Future = std::pin::Pin<
        Box<dyn std::future::Future<Output = Result<Option<Response>, ExceptionCode>> + Send>,
    >;

    fn call(&self, req: Self::Request) -> Self::Future {
        let (answer, delay) = self.answer(req);
        if delay.is_zero() {
            return Box::pin(ready(answer));
        }
        Box::pin(async move {
            tokio::time::sleep(delay).await;
            answer
        })
    }
}

/// Close-on-exec for a pseudo-terminal end (the simulator's M-Bus segments use it too).
pub use crate::sim::endpoint::private;

/// Serves on a new pseudo-terminal; returns the path of its serial end and that end (keep it
/// open so the line survives the gateway closing and reopening it).
pub fn serve_pty(
    mut service: SimService,
    cancel: CancellationToken,
) -> io::Result<(PathBuf, TTYPort)> {
    let (master, slave) = TTYPort::pair().map_err(io::Error::other)?;
    let (master, slave) = (private(master), private(slave));
    let probe = slave
        .try_clone_native()
        .map(private)
        .map_err(io::Error::other)?;
    service.speed = Some(std::sync::Arc::new(std::sync::Mutex::new(probe)));
    let path = slave
        .name()
        .map(PathBuf::from)
        .ok_or_else(|| io::Error::other("pseudo-terminal has no name"))?;
    serve_port(master, service, cancel);
    Ok((path, slave))
}

/// Serves Modbus RTU on `port` until `cancel`. A request tokio-modbus cannot decode (line
/// noise) ends its server loop, so the loop is started again on a duplicate of the port.
pub fn serve_port(port: TTYPort, service: SimService, cancel: CancellationToken) {
    tokio::spawn(async move {
        let mut port = port;
        loop {
            let Ok(spare) = port.try_clone_native().map(private) else {
                tracing::warn!("simulated RTU bus: cannot duplicate the port");
                return;
            };
            let stream = match SerialStream::try_from(port) {
                Ok(s) => s,
                Err(e) => {
                    tracing::warn!("simulated RTU bus: {e}");
                    return;
                }
            };
            let server = tokio_modbus::server::rtu::Server::new(stream);
            let c = cancel.clone();
            match server
                .serve_until(service.clone(), async move { c.cancelled().await })
                .await
            {
                Ok(_) => return,
                Err(e) => tracing::debug!("simulated RTU bus: {e}; serving on"),
            }
            port = spare;
        }
    });
}

/// Serves Modbus TCP on `addr` (port 0 picks a free one); returns the bound address.
pub async fn serve_tcp(
    addr: SocketAddr,
    service: SimService,
    cancel: CancellationToken,
) -> io::Result<SocketAddr> {
    let listener = tokio::net::TcpListener::bind(addr).await?;
    let bound = listener.local_addr()?;
    let server = tokio_modbus::server::tcp::Server::new(listener);
    tokio::spawn(async move {
        let on_connected = |stream, _addr| {
            let service = service.clone();
            async move { Ok(Some((service, stream))) }
        };
        let on_error = |e| tracing::debug!("simulated TCP connection ended: {e}");
        tokio::select! {
            r = server.serve(&on_connected, on_error) => {
                if let Err(e) = r { tracing::warn!("simulated TCP bus stopped: {e}"); }
            }
            () = cancel.cancelled() => {}
        }
    });
    Ok(bound)
}

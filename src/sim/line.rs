//! A line emulator between the gateway and a simulated bus: bytes cross no faster than the baud
//! rate allows (10 bits a character), the module answers after its turnaround, and the line can
//! drop and corrupt bytes at given rates. RS-485 is half duplex: both directions share the line.
//!
//! Runs on two OS threads with blocking pseudo-terminal I/O and precise sleeps, so its timing
//! does not depend on the async runtime's millisecond timer.

use std::io::{Read, Write};
use std::path::PathBuf;
use std::sync::atomic::{AtomicBool, AtomicU64, Ordering};
use std::sync::{Arc, Mutex};
use std::thread::JoinHandle;
use std::time::{Duration, Instant};

use serialport::TTYPort;

/// How the emulated line behaves.
#[derive(Debug, Clone, Copy, PartialEq, serde::Deserialize)]
#[serde(deny_unknown_fields)]
pub struct LineSpec {
    pub baud: u32,
    /// The module's answer delay after the request's last byte.
    #[serde(default, with = "humantime_serde")]
    pub turnaround: Duration,
    /// Share of bytes lost on the line (0..1).
    #[serde(default)]
    pub drop: f64,
    /// Share of bytes with a flipped bit (0..1).
    #[serde(default)]
    pub corrupt: f64,
}

impl LineSpec {
    /// Time of one character on the wire: start, 8 data and stop bit.
    pub fn char_time(&self) -> Duration {
        Duration::from_secs_f64(10.0 / f64::from(self.baud))
    }
}

/// Bytes the line dropped and corrupted.
#[derive(Debug, Default)]
pub struct LineCounters {
    pub dropped: AtomicU64,
    pub corrupted: AtomicU64,
    pub bytes: AtomicU64,
}

/// A running line emulator.
pub struct Line {
    /// The serial device the gateway opens.
    pub gateway_path: PathBuf,
    pub counters: Arc<LineCounters>,
    stop: Arc<AtomicBool>,
    threads: Vec<JoinHandle<()>>,
    _gateway_end: TTYPort,
    _module_end: TTYPort,
}

/// A small deterministic generator for fault injection (xorshift64*).
struct Rng(u64);

impl Rng {
    fn unit(&mut self) -> f64 {
        self.0 ^= self.0 >> 12;
        self.0 ^= self.0 << 25;
        self.0 ^= self.0 >> 27;
        (self.0.wrapping_mul(0x2545_F491_4F6C_DD1D) >> 11) as f64 / (1u64 << 53) as f64
    }
}

/// Sleeps until `t`: the OS sleep for the bulk, a short spin for the last stretch.
fn sleep_until(t: Instant) {
    const SPIN: Duration = Duration::from_micros(30);
    let now = Instant::now();
    if t > now + SPIN {
        std::thread::sleep(t - now - SPIN);
    }
    while Instant::now() < t {
        std::hint::spin_loop();
    }
}

impl Line {
    /// Starts a line; returns it and the path of the pseudo-terminal the module side (the
    /// simulator's RTU server) opens.
    pub fn start(spec: LineSpec, seed: u64) -> std::io::Result<(Line, PathBuf)> {
        use super::server::private;
        let (gw_master, gw_slave) = TTYPort::pair().map_err(std::io::Error::other)?;
        let (mod_master, mod_slave) = TTYPort::pair().map_err(std::io::Error::other)?;
        let (gw_master, gw_slave) = (private(gw_master), private(gw_slave));
        let (mod_master, mod_slave) = (private(mod_master), private(mod_slave));
        let name = |p: &TTYPort| {
            use serialport::SerialPort;
            p.name()
                .map(PathBuf::from)
                .ok_or_else(|| std::io::Error::other("pseudo-terminal has no name"))
        };
        let gateway_path = name(&gw_slave)?;
        let module_path = name(&mod_slave)?;
        let stop = Arc::new(AtomicBool::new(false));
        let counters = Arc::new(LineCounters::default());
        // When the line is next free: RS-485 is half duplex.
        let line_free = Arc::new(Mutex::new(Instant::now()));
        let clone = |p: &TTYPort| {
            p.try_clone_native()
                .map(private)
                .map_err(std::io::Error::other)
        };
        let mut threads = Vec::new();
        for (from, to, delay, seed, to_module) in [
            (
                clone(&gw_master)?,
                clone(&mod_master)?,
                Duration::ZERO,
                seed,
                true,
            ),
            (
                clone(&mod_master)?,
                clone(&gw_master)?,
                spec.turnaround,
                seed ^ 0x9E37_79B9_7F4A_7C15,
                false,
            ),
        ] {
            let stop = stop.clone();
            let counters = counters.clone();
            let line_free = line_free.clone();
            threads.push(std::thread::spawn(move || {
                carry(
                    from,
                    to,
                    spec,
                    delay,
                    Rng(seed | 1),
                    &stop,
                    &counters,
                    &line_free,
                    to_module,
                )
            }));
        }
        Ok((
            Line {
                gateway_path,
                counters,
                stop,
                threads,
                _gateway_end: gw_slave,
                _module_end: mod_slave,
            },
            module_path,
        ))
    }
}

#[allow(clippy::too_many_arguments)] // one thread's whole world, passed once
fn carry(
    mut from: TTYPort,
    mut to: TTYPort,
    spec: LineSpec,
    delay: Duration,
    mut rng: Rng,
    stop: &AtomicBool,
    counters: &LineCounters,
    line_free: &Mutex<Instant>,
    to_module: bool,
) {
    use serialport::SerialPort;
    crate::bus::link::fine_timer_slack();
    let _ = from.set_timeout(Duration::from_millis(50));
    let mut buf = [0u8; 512];
    while !stop.load(Ordering::Relaxed) {
        let n = match from.read(&mut buf) {
            Ok(0) => continue,
            Ok(n) => n,
            Err(e) if e.kind() == std::io::ErrorKind::TimedOut => continue,
            Err(_) => {
                std::thread::sleep(Duration::from_millis(20));
                continue;
            }
        };
        let arrived = Instant::now();
        let mut out = Vec::with_capacity(n);
        for &b in &buf[..n] {
            if spec.drop > 0.0 && rng.unit() < spec.drop {
                counters.dropped.fetch_add(1, Ordering::Relaxed);
                continue;
            }
            if spec.corrupt > 0.0 && rng.unit() < spec.corrupt {
                counters.corrupted.fetch_add(1, Ordering::Relaxed);
                out.push(b ^ (1 << (rng.unit() * 8.0) as u32));
                continue;
            }
            out.push(b);
        }
        counters.bytes.fetch_add(n as u64, Ordering::Relaxed);
        // A module's frame layer discards a request whose CRC fails and resynchronises on the
        // silence after it (Modbus over Serial Line, RTU framing): it never reads the next
        // request as the rest of a broken one. The simulator's server has no silence timing, so
        // the broken frame is discarded here, where the timing is.
        if to_module && out.as_slice() != &buf[..n] {
            out.clear();
        }
        // The bytes occupy the line (dropped ones too: they were sent) from when it is free.
        let done = {
            let mut free = line_free.lock().unwrap_or_else(|e| e.into_inner());
            // The module's turnaround counts from the end of the request (the line's last use),
            // not from when the simulator happened to answer.
            let start = arrived.max(*free + delay);
            *free = start + spec.char_time() * n as u32;
            *free
        };
        sleep_until(done);
        if !out.is_empty() {
            let _ = to.write_all(&out);
        }
    }
}

impl Drop for Line {
    fn drop(&mut self) {
        self.stop.store(true, Ordering::Relaxed);
        for t in self.threads.drain(..) {
            let _ = t.join();
        }
    }
}

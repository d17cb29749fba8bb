//! A line emulator between the gateway and a simulated bus: bytes cross no faster than the baud
//! rate allows (10 bits a character), the module answers after its turnaround, and the line can
//! drop and corrupt bytes at given rates. RS-485 is half duplex: both directions share the line.
//!
//! The noise is seeded and even: every run of [`NOISE_RUN`] bytes in each direction holds exactly
//! its share of dropped and corrupted bytes (at places a seeded generator picks), so a test on a
//! noisy line sees the same amount of noise every time, with no lucky or unlucky streaks; and it
//! can be switched off and on while the line runs ([`Line::set_noisy`]).
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
    /// The noise generator's seed (by default one per bus of the plant).
    #[serde(default)]
    pub seed: Option<u64>,
    /// Answers reach the gateway byte by byte, each when its character is through, as from a
    /// UART without a FIFO or a USB adapter polled every millisecond. Otherwise (the default) a
    /// frame arrives at once when its last character is through, as from a USB adapter that
    /// holds bytes until the line goes quiet.
    #[serde(default)]
    pub trickle: bool,
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
    /// Whether the configured noise is on (it is at the start).
    noisy: Arc<AtomicBool>,
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

/// Bytes over which the noise holds its exact share.
pub const NOISE_RUN: usize = 100;

/// What the line does to one byte.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
enum Fault {
    Dropped,
    /// This bit flipped.
    Flipped(u8),
}

/// Seeded, even noise: in every run of [`NOISE_RUN`] bytes, exactly the configured shares of
/// dropped and corrupted bytes (carried over from run to run where a share is fractional), at
/// places the generator picks. Pure.
struct Noise {
    rng: Rng,
    drop: f64,
    corrupt: f64,
    /// Runs made so far; the faults of the current run, by position.
    runs: u64,
    run: [Option<Fault>; NOISE_RUN],
    at: usize,
}

impl Noise {
    fn new(drop: f64, corrupt: f64, seed: u64) -> Noise {
        Noise {
            rng: Rng(seed | 1),
            drop: drop.clamp(0.0, 1.0),
            corrupt: corrupt.clamp(0.0, 1.0),
            runs: 0,
            run: [None; NOISE_RUN],
            at: NOISE_RUN,
        }
    }

    /// Faults of the `n`-th run at `share`: the whole faults of runs 0..=n less those of 0..n.
    fn faults_in_run(share: f64, n: u64) -> usize {
        let upto = |runs: u64| (share * NOISE_RUN as f64 * runs as f64 + 1e-9).floor() as usize;
        upto(n + 1) - upto(n)
    }

    /// Places the next run's faults: a seeded shuffle of the positions, drops first.
    fn next_run(&mut self) {
        let drops = Noise::faults_in_run(self.drop, self.runs);
        let flips =
            Noise::faults_in_run(self.corrupt, self.runs).min(NOISE_RUN - drops.min(NOISE_RUN));
        self.runs += 1;
        let mut places: [usize; NOISE_RUN] = std::array::from_fn(|i| i);
        for i in (1..NOISE_RUN).rev() {
            let j = (self.rng.unit() * (i + 1) as f64) as usize;
            places.swap(i, j.min(i));
        }
        self.run = [None; NOISE_RUN];
        for (k, &p) in places.iter().enumerate().take(drops + flips) {
            self.run[p] = Some(if k < drops {
                Fault::Dropped
            } else {
                Fault::Flipped((self.rng.unit() * 8.0) as u8 & 7)
            });
        }
        self.at = 0;
    }

    /// What happens to the next byte.
    fn next(&mut self) -> Option<Fault> {
        if self.at == NOISE_RUN {
            self.next_run();
        }
        self.at += 1;
        self.run[self.at - 1]
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

/// The path a pseudo-terminal's end is opened by.
fn pty_name(p: &TTYPort) -> std::io::Result<PathBuf> {
    use serialport::SerialPort;
    p.name()
        .map(PathBuf::from)
        .ok_or_else(|| std::io::Error::other("pseudo-terminal has no name"))
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
        let gateway_path = pty_name(&gw_slave)?;
        let module_path = pty_name(&mod_slave)?;
        let stop = Arc::new(AtomicBool::new(false));
        let noisy = Arc::new(AtomicBool::new(true));
        let seed = spec.seed.unwrap_or(seed);
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
            let noisy = noisy.clone();
            let counters = counters.clone();
            let line_free = line_free.clone();
            threads.push(std::thread::spawn(move || {
                carry(
                    from,
                    to,
                    spec,
                    delay,
                    Noise::new(spec.drop, spec.corrupt, seed),
                    (&stop, &noisy),
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
                noisy,
                threads,
                _gateway_end: gw_slave,
                _module_end: mod_slave,
            },
            module_path,
        ))
    }

    /// Switches the configured noise off (`false`) or on again; the line's timing stays.
    pub fn set_noisy(&self, on: bool) {
        self.noisy.store(on, Ordering::Relaxed);
    }
}

#[allow(clippy::too_many_arguments)] // one thread's whole world, passed once
fn carry(
    mut from: TTYPort,
    mut to: TTYPort,
    spec: LineSpec,
    delay: Duration,
    mut noise: Noise,
    (stop, noisy): (&AtomicBool, &AtomicBool),
    counters: &LineCounters,
    line_free: &Mutex<Instant>,
    to_module: bool,
) {
    use serialport::SerialPort;
    crate::modbus::driver::link::fine_timer_slack();
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
        let noisy = noisy.load(Ordering::Relaxed);
        for &b in &buf[..n] {
            match noisy.then(|| noise.next()).flatten() {
                Some(Fault::Dropped) => {
                    counters.dropped.fetch_add(1, Ordering::Relaxed);
                }
                Some(Fault::Flipped(bit)) => {
                    counters.corrupted.fetch_add(1, Ordering::Relaxed);
                    out.push(b ^ (1 << bit));
                }
                None => out.push(b),
            }
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
        let (start, done) = {
            let mut free = line_free.lock().unwrap_or_else(|e| e.into_inner());
            // The module's turnaround counts from the end of the request (the line's last use),
            // not from when the simulator happened to answer.
            let start = arrived.max(*free + delay);
            *free = start + spec.char_time() * n as u32;
            (start, *free)
        };
        if spec.trickle && !to_module {
            for (i, b) in out.iter().enumerate() {
                sleep_until(start + spec.char_time() * (i as u32 + 1));
                let _ = to.write_all(&[*b]);
            }
            continue;
        }
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

#[cfg(test)]
mod tests {
    use super::*;

    fn faults(noise: &mut Noise, bytes: usize) -> (usize, usize) {
        let (mut dropped, mut flipped) = (0, 0);
        for _ in 0..bytes {
            match noise.next() {
                Some(Fault::Dropped) => dropped += 1,
                Some(Fault::Flipped(bit)) => {
                    assert!(bit < 8);
                    flipped += 1;
                }
                None => {}
            }
        }
        (dropped, flipped)
    }

    #[test]
    fn every_run_of_100_bytes_holds_exactly_its_share_of_noise() {
        let mut noise = Noise::new(0.03, 0.01, 7);
        for _ in 0..50 {
            assert_eq!(faults(&mut noise, NOISE_RUN), (3, 1));
        }
    }

    #[test]
    fn a_fractional_share_is_carried_from_run_to_run() {
        let mut noise = Noise::new(0.025, 0.005, 7);
        assert_eq!(faults(&mut noise, 10 * NOISE_RUN), (25, 5));
    }

    #[test]
    fn the_same_seed_makes_the_same_noise_and_another_seed_other_places() {
        let places = |seed| {
            let mut noise = Noise::new(0.03, 0.01, seed);
            (0..1000).map(|_| noise.next()).collect::<Vec<_>>()
        };
        assert_eq!(places(7), places(7));
        assert_ne!(places(7), places(8));
    }

    #[test]
    fn a_clean_line_has_no_noise() {
        assert_eq!(faults(&mut Noise::new(0.0, 0.0, 7), 1000), (0, 0));
    }
}

//! A microsecond timer on the runtime's own thread, for the RTU silent interval and the
//! transaction timeouts.
//!
//! The runtime's timer ticks in milliseconds: rounded up, the 1.75 ms silent interval at
//! 115200 baud would cost a third of the line. Sleeping the last stretch on a blocking-pool
//! thread is precise but costs a thread hop per transaction (futex wake, the thread's sleep, an
//! eventfd write to wake the runtime again). A Linux timerfd armed for the interval and watched
//! by the runtime's own epoll wakes once, on time (hrtimer, no timer slack), with no other
//! thread involved: three system calls (arm, wait, read).

use std::io;
use std::os::fd::{AsRawFd, FromRawFd, OwnedFd};
use std::task::{Context, Poll, ready};
use std::time::Duration;

use tokio::io::Interest;
use tokio::io::unix::AsyncFd;
use tokio::time::Instant;

/// A one-shot timerfd registered with the runtime.
pub struct FineTimer(AsyncFd<OwnedFd>);

impl FineTimer {
    /// A timer on the monotonic clock (the clock of `std`/`tokio` instants on Linux).
    pub fn new() -> io::Result<FineTimer> {
        // SAFETY: timerfd_create takes a clock id and flags and returns a new descriptor or -1.
        let fd = unsafe {
            libc::timerfd_create(
                libc::CLOCK_MONOTONIC,
                libc::TFD_NONBLOCK | libc::TFD_CLOEXEC,
            )
        };
        if fd < 0 {
            return Err(io::Error::last_os_error());
        }
        // SAFETY: `fd` was just created and is owned by nobody else.
        let owned = unsafe { OwnedFd::from_raw_fd(fd) };
        // SAFETY: the AsyncFd owns the descriptor and nothing replaces or closes it meanwhile.
        let registered = unsafe { AsyncFd::register_with_interest(owned, Interest::READABLE)? };
        Ok(FineTimer(registered))
    }

    /// Waits until `t`. Never returns early; an error means the timer could not be used (the
    /// caller falls back to the runtime's timer, which never wakes early either).
    pub async fn sleep_until(&self, t: Instant) -> io::Result<()> {
        let rest = t.saturating_duration_since(Instant::now());
        if rest.is_zero() {
            return Ok(());
        }
        self.arm(rest)?;
        std::future::poll_fn(|cx| self.poll_expired(cx)).await
    }

    /// Arms the timer for `t` (at once if that has passed).
    pub fn arm_at(&self, t: Instant) -> io::Result<()> {
        let rest = t.saturating_duration_since(Instant::now());
        self.arm(rest.max(Duration::from_nanos(1)))
    }

    /// Ready once the armed time has come.
    pub fn poll_expired(&self, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        loop {
            let mut ready = ready!(self.0.poll_read_ready(cx))?;
            let mut expirations = [0u8; 8];
            // SAFETY: reads 8 bytes (the expiration count) into a buffer of 8 bytes.
            match ready.try_io(|fd| {
                let n = unsafe {
                    libc::read(
                        fd.as_raw_fd(),
                        expirations.as_mut_ptr().cast(),
                        expirations.len(),
                    )
                };
                if n < 0 {
                    Err(io::Error::last_os_error())
                } else {
                    Ok(())
                }
            }) {
                Ok(Ok(())) => {
                    // Read: nothing more until the next arming (saves a read that would only
                    // say "would block" at the next wait).
                    ready.clear_ready();
                    return Poll::Ready(Ok(()));
                }
                Ok(Err(e)) => return Poll::Ready(Err(e)),
                // Readiness left over from an earlier expiration: wait for this one.
                Err(_would_block) => continue,
            }
        }
    }

    /// Arms the timer to expire once, `after` from now (re-arming clears earlier expirations).
    fn arm(&self, after: Duration) -> io::Result<()> {
        let spec = libc::itimerspec {
            it_interval: libc::timespec {
                tv_sec: 0,
                tv_nsec: 0,
            },
            it_value: libc::timespec {
                tv_sec: after.as_secs() as libc::time_t,
                tv_nsec: after.subsec_nanos() as libc::c_long,
            },
        };
        // SAFETY: a valid timerfd and a fully initialised itimerspec; the old value is not asked.
        let r =
            unsafe { libc::timerfd_settime(self.0.as_raw_fd(), 0, &spec, std::ptr::null_mut()) };
        if r < 0 {
            return Err(io::Error::last_os_error());
        }
        Ok(())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[tokio::test]
    async fn the_timer_never_wakes_early_and_wakes_within_a_millisecond() {
        let timer = FineTimer::new().unwrap();
        for micros in [300u64, 1750, 3646, 50] {
            let start = Instant::now();
            let t = start + Duration::from_micros(micros);
            timer.sleep_until(t).await.unwrap();
            let woke = Instant::now();
            assert!(woke >= t, "woke {:?} early", t - woke);
            // Only that it wakes at all: how late it wakes is a figure for the benchmark
            // (`cargo bench --bench line`, docs/benchmarks.md), not a bar for a test that a
            // loaded machine's scheduler decides.
            assert!(woke - t < Duration::from_secs(2), "{:?} late", woke - t);
        }
    }

    #[tokio::test]
    async fn an_abandoned_wait_does_not_end_the_next_one_early() {
        let timer = FineTimer::new().unwrap();
        // Armed for 1 ms, abandoned: its expiration must not count for the next wait.
        let _ = tokio::time::timeout(
            Duration::from_micros(10),
            timer.sleep_until(Instant::now() + Duration::from_millis(1)),
        )
        .await;
        tokio::time::sleep(Duration::from_millis(3)).await;
        let start = Instant::now();
        let t = start + Duration::from_millis(5);
        timer.sleep_until(t).await.unwrap();
        assert!(Instant::now() >= t);
    }
}

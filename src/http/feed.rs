//! `GET /api/v1/events`: the status as server-sent events, what the page listens to. One task
//! makes the snapshot once a second while anyone listens and hands the same bytes to every
//! stream, so fifty open pages cost the gateway one snapshot and fifty writes a second: no
//! connection accepted, no request parsed, no answer head made per page and second (what a
//! poll of `/api/v1/status` costs each time).
//!
//! A stream that its client does not read keeps only the newest frame (a `watch`), never a
//! queue; it ends after [`STREAM_LIFE`] (the browser's `EventSource` connects again by itself
//! after the `retry` the first frame names), and holds one of [`STREAMS`] slots, apart from
//! the slots of short requests, so open pages never keep a probe of `/healthz` out.

use std::convert::Infallible;
use std::future::Future;
use std::pin::Pin;
use std::sync::Arc;
use std::task::{Context, Poll};
use std::time::Duration;

use hyper::body::{Body, Bytes, Frame};
use tokio::sync::watch;
use tokio_util::sync::CancellationToken;

use super::slots::Lease;
use crate::status::{FRESH, Live};

/// Streams served at once; a new one beyond them closes the oldest.
pub const STREAMS: usize = 64;
/// A stream's life; then it ends and the browser connects again.
pub const STREAM_LIFE: Duration = Duration::from_secs(300);
/// The stream's content type.
pub const KIND: &str = "text/event-stream";
/// What the browser waits before it connects again, in milliseconds.
const RETRY_MS: u32 = 3000;

/// One event of the stream: `data: <json>` and the blank line that ends it (the JSON is one
/// line: serde writes a newline inside a string as `\n`).
pub fn frame(json: &[u8]) -> Bytes {
    let mut out = Vec::with_capacity(json.len() + 8);
    out.extend_from_slice(b"data: ");
    out.extend_from_slice(json);
    out.extend_from_slice(b"\n\n");
    Bytes::from(out)
}

/// Makes the snapshot once every [`FRESH`] while a stream is open, until `shutdown`.
pub async fn feed(live: Arc<Live>, frames: watch::Sender<Bytes>, shutdown: CancellationToken) {
    let mut tick = tokio::time::interval(FRESH);
    tick.set_missed_tick_behavior(tokio::time::MissedTickBehavior::Delay);
    loop {
        tokio::select! {
            () = shutdown.cancelled() => return,
            _ = tick.tick() => {}
        }
        if frames.receiver_count() > 0 {
            frames.send_replace(frame(&live.made_now().await));
        }
    }
}

type Next = Pin<Box<dyn Future<Output = (Option<Bytes>, watch::Receiver<Bytes>)> + Send>>;

/// The body of one stream: the snapshot at hand at once, then every new one.
pub struct Feed {
    first: Option<Bytes>,
    next: Next,
    end: Pin<Box<tokio::time::Sleep>>,
    _lease: Lease,
}

/// The next frame the feeder sends; `None` once it is gone (the endpoint shuts down).
fn next(mut frames: watch::Receiver<Bytes>) -> Next {
    Box::pin(async move {
        let frame = match frames.changed().await {
            Ok(()) => Some(frames.borrow_and_update().clone()),
            Err(_) => None,
        };
        (frame, frames)
    })
}

impl Feed {
    /// A stream that starts with `json` (the snapshot at hand), holding `lease` while it runs.
    pub fn new(json: &[u8], mut frames: watch::Receiver<Bytes>, lease: Lease) -> Feed {
        frames.mark_unchanged();
        let mut first = format!("retry: {RETRY_MS}\n").into_bytes();
        first.extend_from_slice(&frame(json));
        Feed {
            first: Some(Bytes::from(first)),
            next: next(frames),
            end: Box::pin(tokio::time::sleep(STREAM_LIFE)),
            _lease: lease,
        }
    }
}

impl Body for Feed {
    type Data = Bytes;
    type Error = Infallible;

    fn poll_frame(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
    ) -> Poll<Option<Result<Frame<Bytes>, Infallible>>> {
        if let Some(first) = self.first.take() {
            return Poll::Ready(Some(Ok(Frame::data(first))));
        }
        if self.end.as_mut().poll(cx).is_ready() {
            return Poll::Ready(None);
        }
        match self.next.as_mut().poll(cx) {
            Poll::Pending => Poll::Pending,
            Poll::Ready((None, _)) => Poll::Ready(None),
            Poll::Ready((Some(bytes), frames)) => {
                self.next = next(frames);
                Poll::Ready(Some(Ok(Frame::data(bytes))))
            }
        }
    }
}

#[cfg(test)]
mod tests {
    use std::sync::Mutex;

    use http_body_util::BodyExt;

    use super::super::slots::{Pool, Slots, lock};
    use super::*;

    fn pool() -> Pool {
        Arc::new(Mutex::new(Slots::new(2)))
    }

    #[test]
    fn a_frame_is_one_data_line_and_a_blank_line() {
        assert_eq!(
            &frame(br#"{"a":"x\ny"}"#)[..],
            b"data: {\"a\":\"x\\ny\"}\n\n"
        );
    }

    #[tokio::test(start_paused = true)]
    async fn a_stream_sends_the_snapshot_at_hand_then_only_the_newest_and_ends_with_its_life() {
        let (tx, _) = watch::channel(Bytes::from_static(b"data: stale\n\n"));
        let pool = pool();
        let mut feed = Feed::new(
            b"{}",
            tx.subscribe(),
            Lease::take(&pool, CancellationToken::new()),
        );
        let first = feed.frame().await.unwrap().unwrap().into_data().unwrap();
        assert_eq!(&first[..], b"retry: 3000\ndata: {}\n\n");
        // Two snapshots while the client did not read: it gets the newest, not a queue.
        tx.send_replace(frame(b"1"));
        tx.send_replace(frame(b"2"));
        let second = feed.frame().await.unwrap().unwrap().into_data().unwrap();
        assert_eq!(&second[..], b"data: 2\n\n");
        tokio::time::advance(STREAM_LIFE).await;
        assert!(
            feed.frame().await.is_none(),
            "the stream ends with its life"
        );
        drop(feed);
        assert_eq!(lock(&pool).occupied(), 0, "its slot is given back");
    }

    #[tokio::test]
    async fn a_stream_ends_when_the_feeder_is_gone() {
        let (tx, _) = watch::channel(Bytes::new());
        let pool = pool();
        let mut feed = Feed::new(
            b"{}",
            tx.subscribe(),
            Lease::take(&pool, CancellationToken::new()),
        );
        let _ = feed.frame().await;
        drop(tx);
        assert!(feed.frame().await.is_none());
    }
}

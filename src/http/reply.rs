//! Answers every route shares: plain text, and the headers of the page, its files and its API.

use http_body_util::Full;
use hyper::body::Bytes;
use std::time::Duration;

use hyper::header::{CACHE_CONTROL, CONTENT_TYPE, HeaderName, HeaderValue, RETRY_AFTER};
use hyper::{Response, StatusCode};

/// The page loads only its own files and talks only to its own origin: no inline script or
/// style, no other host, no framing by another page.
pub const CSP: &str =
    "default-src 'self'; base-uri 'none'; form-action 'self'; frame-ancestors 'none'";

/// A plain-text answer.
pub fn plain(status: StatusCode, body: String) -> Response<Full<Bytes>> {
    let mut r = Response::new(Full::new(Bytes::from(body)));
    *r.status_mut() = status;
    r.headers_mut().insert(
        CONTENT_TYPE,
        HeaderValue::from_static("text/plain; charset=utf-8"),
    );
    r
}

/// An answer of the page's: its type, the content security policy, no sniffing, no caching
/// (a gateway updated in place serves its new page at once), no referrer.
pub fn page(status: StatusCode, kind: &'static str, body: Bytes) -> Response<Full<Bytes>> {
    let mut r = dress(Response::new(Full::new(body)), kind);
    *r.status_mut() = status;
    r
}

/// `r` with the headers of the page's answers (see [`page`]), whatever its body.
pub fn dress<B>(mut r: Response<B>, kind: &'static str) -> Response<B> {
    let h = r.headers_mut();
    h.insert(CONTENT_TYPE, HeaderValue::from_static(kind));
    h.insert(CACHE_CONTROL, HeaderValue::from_static("no-store"));
    h.insert(
        HeaderName::from_static("content-security-policy"),
        HeaderValue::from_static(CSP),
    );
    h.insert(
        HeaderName::from_static("x-content-type-options"),
        HeaderValue::from_static("nosniff"),
    );
    h.insert(
        HeaderName::from_static("referrer-policy"),
        HeaderValue::from_static("no-referrer"),
    );
    r
}

/// `r` (a 429) saying when to try again: after `left`, in whole seconds.
pub fn limited<B>(mut r: Response<B>, left: Duration) -> Response<B> {
    r.headers_mut()
        .insert(RETRY_AFTER, HeaderValue::from(whole_seconds(left)));
    r
}

/// `d` in seconds, rounded up (a client that waits that long is in time), at least 1.
pub fn whole_seconds(d: Duration) -> u64 {
    (d.as_secs() + u64::from(d.subsec_nanos() > 0)).max(1)
}

//! The status page: HTML, CSS and JavaScript compiled into the binary (no build step, nothing
//! fetched from elsewhere), and its data at `/api/v1/status`. The script puts every name and
//! unit into the page as text (`textContent`), never as markup: they come from config and
//! profile files.

use http_body_util::Full;
use hyper::body::{Bytes, Incoming};
use hyper::header::{HeaderValue, WWW_AUTHENTICATE};
use hyper::{Request, Response, StatusCode};

use super::auth;
use super::reply;
use crate::config::Secret;
use crate::status::Live;

/// The page's files: path, content type, body.
pub const FILES: &[(&str, &str, &str)] = &[
    (
        "/",
        "text/html; charset=utf-8",
        include_str!("page/index.html"),
    ),
    (
        "/status.css",
        "text/css; charset=utf-8",
        include_str!("page/status.css"),
    ),
    (
        "/status.js",
        "text/javascript; charset=utf-8",
        include_str!("page/status.js"),
    ),
];

/// The login form's style (served without the token: the form is what asks for it).
const LOGIN_CSS: &str = include_str!("page/login.css");

/// The API's path.
pub const API: &str = "/api/v1/status";
/// The same snapshot, pushed once a second as server-sent events (what the page listens to).
pub const EVENTS: &str = "/api/v1/events";

/// A `GET` of anything but `/metrics` and `/healthz`.
pub fn answer(
    path: &str,
    req: &Request<Incoming>,
    live: &Live,
    token: Option<&Secret>,
) -> Response<Full<Bytes>> {
    match path {
        "/login" => return auth::form(StatusCode::OK, ""),
        "/login.css" => {
            let css = Bytes::from_static(LOGIN_CSS.as_bytes());
            return reply::page(StatusCode::OK, "text/css; charset=utf-8", css);
        }
        // Asked for by every browser; nothing to show, and no reason to log a 404.
        "/favicon.ico" => return reply::plain(StatusCode::NO_CONTENT, String::new()),
        _ => {}
    }
    let file = FILES
        .iter()
        .find(|(p, ..)| *p == path || (path == "/index.html" && *p == "/"));
    if file.is_none() && path != API {
        return reply::plain(
            StatusCode::NOT_FOUND,
            format!("/ (the status page), {API}, {EVENTS}, /metrics or /healthz\n"),
        );
    }
    if !auth::allowed(req.headers(), token) {
        return refused(path);
    }
    match file {
        Some((_, kind, body)) => {
            reply::page(StatusCode::OK, kind, Bytes::from_static(body.as_bytes()))
        }
        None => reply::page(StatusCode::OK, "application/json", live.json()),
    }
}

/// 401: the login form for the page itself, a bearer challenge for the rest.
pub fn refused(path: &str) -> Response<Full<Bytes>> {
    let mut r = if path == "/" || path == "/index.html" {
        auth::form(StatusCode::UNAUTHORIZED, "")
    } else {
        reply::plain(
            StatusCode::UNAUTHORIZED,
            "the token is needed (metrics.token)\n".into(),
        )
    };
    let h = r.headers_mut();
    h.insert(
        WWW_AUTHENTICATE,
        HeaderValue::from_static("Bearer realm=\"pulsegate\""),
    );
    r
}

#[cfg(test)]
mod tests {
    use super::*;

    /// The bound the issue sets: the page loads on a slow line in a moment.
    const MOST_BYTES: usize = 150 * 1024;

    #[test]
    fn the_page_and_its_files_stay_under_150_kb_in_all() {
        let login = include_str!("page/login.html").len() + LOGIN_CSS.len();
        let all: usize = FILES.iter().map(|(_, _, b)| b.len()).sum::<usize>() + login;
        assert!(all < MOST_BYTES, "{all} bytes");
    }

    #[test]
    fn the_page_has_no_inline_script_or_style_and_names_no_other_host() {
        for (path, _, body) in FILES {
            assert!(
                !body.contains("http://") && !body.contains("https://"),
                "{path}"
            );
            assert!(
                !body.contains("innerHTML") && !body.contains("outerHTML"),
                "{path}"
            );
            assert!(
                !body.contains("insertAdjacentHTML") && !body.contains("document.write"),
                "{path}"
            );
        }
        let html = FILES[0].2;
        assert!(!html.contains(" style=") && !html.contains("<style"));
        assert!(html.matches("<script").count() == 1 && html.contains("<script src=\"status.js\""));
    }
}

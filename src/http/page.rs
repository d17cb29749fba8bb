//! The status page: HTML, CSS and JavaScript compiled into the binary (no build step, nothing
//! fetched from elsewhere), and its data at `/api/v1/status`. The script puts every name and
//! unit into the page as text (`textContent`), never as markup: they come from config and
//! profile files. The login form (`POST /login`) sets the token's cookie.

use http_body_util::{BodyExt, Full, Limited};
use hyper::body::{Bytes, Incoming};
use hyper::header::{HeaderValue, WWW_AUTHENTICATE};
use hyper::{Request, Response, StatusCode};

use super::auth;
use super::door::{Door, Pass};
use super::lockout::Client;
use super::reply;
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

/// The largest login form body read.
const MAX_FORM: usize = 1024;

/// The API's path.
pub const API: &str = "/api/v1/status";
/// The same snapshot, pushed once a second as server-sent events (what the page listens to).
pub const EVENTS: &str = "/api/v1/events";

/// A `GET` of anything but `/metrics` and `/healthz`, from `client`.
pub async fn answer(
    path: &str,
    req: &Request<Incoming>,
    live: &Live,
    door: &Door,
    client: Client,
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
    if let Some(shut) = shut(path, door.request(client, req.headers())) {
        return shut;
    }
    match file {
        Some((_, kind, body)) => {
            reply::page(StatusCode::OK, kind, Bytes::from_static(body.as_bytes()))
        }
        None => reply::page(StatusCode::OK, "application/json", live.fresh().await),
    }
}

/// `POST /login` with `token=<token>` (a form) from `client`: the cookie and a redirect to the
/// page when it is the token, the form again when not (401), or while `client` is locked out
/// (429).
pub async fn login(req: Request<Incoming>, door: &Door, client: Client) -> Response<Full<Bytes>> {
    let Some(token) = door.token() else {
        return auth::redirect(None);
    };
    let body = match Limited::new(req.into_body(), MAX_FORM).collect().await {
        Ok(b) => b.to_bytes(),
        Err(_) => return auth::form(StatusCode::PAYLOAD_TOO_LARGE, "That was too long."),
    };
    let given = auth::form_value(&body, "token").unwrap_or_default();
    match door.login(client, &given) {
        Pass::Open => auth::redirect(Some(&token.0)),
        Pass::Closed => auth::form(StatusCode::UNAUTHORIZED, "That is not the token."),
        Pass::Limited(left) => limited("/login", left),
    }
}

/// The login form's message to a client that is locked out for `left`.
fn wait(left: std::time::Duration) -> String {
    format!(
        "Too many wrong tokens from this address: try again in {} s.",
        reply::whole_seconds(left)
    )
}

/// What a guarded `path` answers when the door does not open: 401 or 429; `None` when it does.
pub fn shut(path: &str, pass: Pass) -> Option<Response<Full<Bytes>>> {
    match pass {
        Pass::Open => None,
        Pass::Closed => Some(refused(path)),
        Pass::Limited(left) => Some(limited(path, left)),
    }
}

/// Whether `path` is the page itself or the login (a browser's, shown the login form when
/// refused).
fn is_page(path: &str) -> bool {
    matches!(path, "/" | "/index.html" | "/login")
}

/// 429 with `Retry-After`: the login form saying when for the page itself, plain text for the
/// rest.
fn limited(path: &str, left: std::time::Duration) -> Response<Full<Bytes>> {
    let status = StatusCode::TOO_MANY_REQUESTS;
    let r = if is_page(path) {
        auth::form(status, &wait(left))
    } else {
        let s = reply::whole_seconds(left);
        let text = format!("too many wrong tokens from this address: try again in {s} s\n");
        reply::plain(status, text)
    };
    reply::limited(r, left)
}

/// 401: the login form for the page itself, a bearer challenge for the rest.
fn refused(path: &str) -> Response<Full<Bytes>> {
    let mut r = if is_page(path) {
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

//! `metrics.token`: the page, its files and `/api/v1/status` answer only a request that carries
//! it, as `Authorization: Bearer <token>` (scripts) or as the cookie the login form sets
//! (browsers: HttpOnly, so no script reads it; SameSite=Strict, so no other site's page sends
//! it). Compared in constant time: the SHA-256 of both sides, so not even the length leaks.

use http_body_util::{BodyExt, Full, Limited};
use hyper::body::{Bytes, Incoming};
use hyper::header::{AUTHORIZATION, COOKIE, HeaderValue, LOCATION, SET_COOKIE};
use hyper::{HeaderMap, Request, Response, StatusCode};

use super::reply;
use crate::config::Secret;

/// The cookie's name.
pub const COOKIE_NAME: &str = "pulsegate_token";
/// The largest login form body read.
const MAX_FORM: usize = 1024;

/// The login form; `<!--message-->` is where a refusal is said.
const LOGIN: &str = include_str!("page/login.html");

/// Whether `a` and `b` are the same text, in time that does not depend on where they differ.
pub fn same(a: &str, b: &str) -> bool {
    use ring::digest::{SHA256, digest};
    let (a, b) = (digest(&SHA256, a.as_bytes()), digest(&SHA256, b.as_bytes()));
    // Every byte looked at whatever the first difference (and of digests: a difference says
    // nothing of where the texts differ).
    let diff = a
        .as_ref()
        .iter()
        .zip(b.as_ref())
        .fold(0u8, |acc, (x, y)| acc | (x ^ y));
    std::hint::black_box(diff) == 0
}

/// Whether a request may see the page and the API: no token configured, or it carries it.
pub fn allowed(headers: &HeaderMap, token: Option<&Secret>) -> bool {
    let Some(token) = token else { return true };
    let bearer = headers
        .get_all(AUTHORIZATION)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .filter_map(|v| v.strip_prefix("Bearer "))
        .any(|t| same(t.trim(), &token.0));
    bearer || cookie(headers).is_some_and(|t| same(t, &token.0))
}

/// The token cookie's value, if the request has one.
fn cookie(headers: &HeaderMap) -> Option<&str> {
    headers
        .get_all(COOKIE)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(';'))
        .filter_map(|kv| kv.trim().split_once('='))
        .find(|(k, _)| *k == COOKIE_NAME)
        .map(|(_, v)| v)
}

/// The login form, with `message` (fixed text of ours, never what a client sent).
pub fn form(status: StatusCode, message: &str) -> Response<Full<Bytes>> {
    let body = LOGIN.replace("<!--message-->", message);
    reply::page(status, "text/html; charset=utf-8", Bytes::from(body))
}

/// `POST /login` with `token=<token>` (a form): the cookie and a redirect to the page when it
/// is the token, the form again (401) when not.
pub async fn login(req: Request<Incoming>, token: Option<&Secret>) -> Response<Full<Bytes>> {
    let Some(token) = token else {
        return redirect(None);
    };
    let body = match Limited::new(req.into_body(), MAX_FORM).collect().await {
        Ok(b) => b.to_bytes(),
        Err(_) => return form(StatusCode::PAYLOAD_TOO_LARGE, "That was too long."),
    };
    let given = form_value(&body, "token").unwrap_or_default();
    if !same(&given, &token.0) {
        tracing::info!("status page: a login with a wrong token");
        return form(StatusCode::UNAUTHORIZED, "That is not the token.");
    }
    redirect(Some(&token.0))
}

/// 303 to the page, setting the cookie when `token` is given.
fn redirect(token: Option<&str>) -> Response<Full<Bytes>> {
    let mut r = reply::plain(StatusCode::SEE_OTHER, String::new());
    r.headers_mut()
        .insert(LOCATION, HeaderValue::from_static("/"));
    if let Some(token) = token {
        let cookie = format!("{COOKIE_NAME}={token}; Path=/; HttpOnly; SameSite=Strict");
        if let Ok(v) = HeaderValue::from_str(&cookie) {
            r.headers_mut().insert(SET_COOKIE, v);
        }
    }
    r
}

/// A field of an `application/x-www-form-urlencoded` body, decoded.
fn form_value(body: &[u8], key: &str) -> Option<String> {
    let text = std::str::from_utf8(body).ok()?;
    let raw = text
        .split('&')
        .filter_map(|kv| kv.split_once('='))
        .find(|(k, _)| *k == key)?
        .1;
    let mut out = Vec::with_capacity(raw.len());
    let mut bytes = raw.bytes();
    while let Some(b) = bytes.next() {
        match b {
            b'+' => out.push(b' '),
            b'%' => {
                let hex = [bytes.next()?, bytes.next()?];
                let hex = std::str::from_utf8(&hex).ok()?;
                out.push(u8::from_str_radix(hex, 16).ok()?);
            }
            b => out.push(b),
        }
    }
    String::from_utf8(out).ok()
}

#[cfg(test)]
mod tests {
    use super::*;

    fn headers(pairs: &[(&'static str, &str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(*k, HeaderValue::from_str(v).unwrap());
        }
        h
    }

    #[test]
    fn without_a_token_configured_everyone_may_look() {
        assert!(allowed(&HeaderMap::new(), None));
    }

    #[test]
    fn the_token_is_taken_as_a_bearer_or_as_the_cookie_and_nothing_else() {
        let t = Secret("0123456789abcdef".into());
        assert!(!allowed(&HeaderMap::new(), Some(&t)));
        assert!(allowed(
            &headers(&[("authorization", "Bearer 0123456789abcdef")]),
            Some(&t)
        ));
        assert!(!allowed(
            &headers(&[("authorization", "Bearer 0123456789abcdeX")]),
            Some(&t)
        ));
        assert!(!allowed(
            &headers(&[("authorization", "Basic 0123456789abcdef")]),
            Some(&t)
        ));
        assert!(allowed(
            &headers(&[("cookie", "a=b; pulsegate_token=0123456789abcdef")]),
            Some(&t)
        ));
        assert!(!allowed(
            &headers(&[("cookie", "pulsegate_token=0123")]),
            Some(&t)
        ));
        assert!(!allowed(
            &headers(&[("cookie", "other=0123456789abcdef")]),
            Some(&t)
        ));
    }

    #[test]
    fn a_login_form_field_is_decoded() {
        assert_eq!(
            form_value(b"token=a%2Bb+c", "token").as_deref(),
            Some("a+b c")
        );
        assert_eq!(
            form_value(b"x=1&token=abc", "token").as_deref(),
            Some("abc")
        );
        assert_eq!(form_value(b"token=%zz", "token"), None);
        assert_eq!(form_value(b"nothing", "token"), None);
    }

    #[test]
    fn the_same_text_is_the_same_and_any_other_is_not() {
        assert!(same("abc", "abc"));
        assert!(!same("abc", "abd"));
        assert!(!same("abc", "abcd"));
    }
}

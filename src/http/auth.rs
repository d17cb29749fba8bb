//! `metrics.token`: the page, its files and `/api/v1/status` answer only a request that carries
//! it, as `Authorization: Bearer <token>` (scripts) or as the cookie the login form sets
//! (browsers: HttpOnly, so no script reads it; SameSite=Strict, so no other site's page sends
//! it). Compared in constant time: the SHA-256 of both sides, so not even the length leaks.
//! Whether a token is compared at all, and what a wrong one costs, is `door.rs`'s.

use http_body_util::Full;
use hyper::body::Bytes;
use hyper::header::{AUTHORIZATION, COOKIE, HeaderValue, LOCATION, SET_COOKIE};
use hyper::{HeaderMap, Response, StatusCode};

use super::reply;
use crate::config::Secret;

/// The cookie's name.
pub const COOKIE_NAME: &str = "pulsegate_token";

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

/// The tokens a request gives: its bearers (`Authorization: Bearer <token>`) and its cookie.
pub fn given(headers: &HeaderMap) -> Vec<&str> {
    headers
        .get_all(AUTHORIZATION)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .filter_map(|v| v.strip_prefix("Bearer "))
        .map(str::trim)
        .chain(cookie(headers))
        .collect()
}

/// Whether any of `given` is `token`.
pub fn any_is(given: &[&str], token: &Secret) -> bool {
    given.iter().any(|t| same(t, &token.0))
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

/// 303 to the page, setting the cookie when `token` is given.
pub fn redirect(token: Option<&str>) -> Response<Full<Bytes>> {
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
pub fn form_value(body: &[u8], key: &str) -> Option<String> {
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
    fn the_token_is_taken_as_a_bearer_or_as_the_cookie_and_nothing_else() {
        let t = Secret("0123456789abcdef".into());
        let given = |pairs: &[(&'static str, &str)]| {
            let h = headers(pairs);
            let g = given(&h);
            (g.len(), any_is(&g, &t))
        };
        assert_eq!(given(&[]), (0, false));
        let bearer = "Bearer 0123456789abcdef";
        assert_eq!(given(&[("authorization", bearer)]), (1, true));
        let wrong = "Bearer 0123456789abcdeX";
        assert_eq!(given(&[("authorization", wrong)]), (1, false));
        let basic = "Basic 0123456789abcdef";
        assert_eq!(given(&[("authorization", basic)]), (0, false));
        let cookie = "a=b; pulsegate_token=0123456789abcdef";
        assert_eq!(given(&[("cookie", cookie)]), (1, true));
        let short = "pulsegate_token=0123";
        assert_eq!(given(&[("cookie", short)]), (1, false));
        let other = "other=0123456789abcdef";
        assert_eq!(given(&[("cookie", other)]), (0, false));
        let both = [("authorization", wrong), ("cookie", cookie)];
        assert_eq!(given(&both), (2, true), "any of them may be it");
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

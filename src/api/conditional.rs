//! Conditional requests (RFC 9110 `ETag` / `If-None-Match`) and `Prefer: wait=N`
//! (RFC 7240).

use axum::body::Body;
use axum::http::{header, HeaderMap, HeaderValue, StatusCode};
use axum::response::Response;
use sha2::{Digest, Sha256};

/// Longest honoured `Prefer: wait`, in seconds.
pub const MAX_WAIT_SECS: u64 = 60;

/// A strong entity tag of a representation.
pub fn etag_of(body: &[u8]) -> String {
    let d = Sha256::digest(body);
    format!("\"{}\"", hex::encode(&d[..16]))
}

/// Whether `If-None-Match` names this tag (weak comparison, `*` matches anything).
pub fn none_match_hits(headers: &HeaderMap, etag: &str) -> bool {
    headers
        .get_all(header::IF_NONE_MATCH)
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .map(str::trim)
        .any(|t| t == "*" || t.strip_prefix("W/").unwrap_or(t) == etag)
}

/// The `wait` preference in seconds, capped at [`MAX_WAIT_SECS`]; None when absent or
/// malformed (a preference that cannot be read is ignored, as RFC 7240 asks).
pub fn prefer_wait(headers: &HeaderMap) -> Option<u64> {
    headers
        .get_all("prefer")
        .iter()
        .filter_map(|v| v.to_str().ok())
        .flat_map(|v| v.split(','))
        .filter_map(|p| {
            let p = p.split(';').next()?.trim();
            let (k, v) = p.split_once('=')?;
            if !k.trim().eq_ignore_ascii_case("wait") {
                return None;
            }
            v.trim().trim_matches('"').parse::<u64>().ok()
        })
        .next()
        .map(|n| n.min(MAX_WAIT_SECS))
}

/// A JSON representation with its `ETag`, or 304 when the client has it already.
/// `applied_wait` adds `Preference-Applied: wait=N`.
pub fn json_with_etag(headers: &HeaderMap, body: Vec<u8>, applied_wait: Option<u64>) -> Response {
    let etag = etag_of(&body);
    let hit = none_match_hits(headers, &etag);
    let mut resp = if hit {
        Response::new(Body::empty())
    } else {
        Response::new(Body::from(body))
    };
    let h = resp.headers_mut();
    if hit {
        *resp.status_mut() = StatusCode::NOT_MODIFIED;
    } else {
        h.insert(
            header::CONTENT_TYPE,
            HeaderValue::from_static("application/json"),
        );
    }
    let h = resp.headers_mut();
    if let Ok(v) = HeaderValue::from_str(&etag) {
        h.insert(header::ETAG, v);
    }
    if let Some(n) = applied_wait {
        if let Ok(v) = HeaderValue::from_str(&format!("wait={n}")) {
            h.insert("preference-applied", v);
        }
    }
    resp
}

#[cfg(test)]
mod tests {
    use super::*;

    fn hm(pairs: &[(&'static str, &'static str)]) -> HeaderMap {
        let mut h = HeaderMap::new();
        for (k, v) in pairs {
            h.append(*k, HeaderValue::from_static(v));
        }
        h
    }

    #[test]
    fn prefer_wait_is_read_capped_and_other_preferences_ignored() {
        assert_eq!(prefer_wait(&hm(&[("prefer", "wait=5")])), Some(5));
        assert_eq!(
            prefer_wait(&hm(&[("prefer", "respond-async, wait=100")])),
            Some(60)
        );
        assert_eq!(prefer_wait(&hm(&[("prefer", "return=minimal")])), None);
        assert_eq!(prefer_wait(&hm(&[("prefer", "wait=soon")])), None);
        assert_eq!(prefer_wait(&hm(&[])), None);
    }

    #[test]
    fn if_none_match_compares_weakly_and_in_lists() {
        let tag = etag_of(b"{}");
        let list = format!("\"x\", W/{tag}");
        let mut h = HeaderMap::new();
        h.insert(header::IF_NONE_MATCH, HeaderValue::from_str(&list).unwrap());
        assert!(none_match_hits(&h, &tag));
        assert!(!none_match_hits(&h, &etag_of(b"[]")));
        assert!(none_match_hits(&hm(&[("if-none-match", "*")]), &tag));
    }
}

//! Webhooks: the URL policy, Standard Webhooks signatures, and the dispatcher that
//! delivers queued notifications with exponential backoff (the queue lives in the store,
//! so retries survive restarts).

use base64::Engine;
use hmac::{Hmac, Mac};
use sha2::Sha256;
use std::net::IpAddr;
use std::time::Duration;
use tokio_util::sync::CancellationToken;

use crate::store::webhooks::{now_ms, Attempt, DueWebhook};
use crate::store::{JobRecord, Store};

/// Deliveries are retried for this long after the first attempt.
pub const GIVE_UP_AFTER_MS: i64 = 24 * 3600 * 1000;

/// Why a webhook URL is refused.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum UrlRefusal {
    #[error("webhook_url is not a valid http or https URL: {0}")]
    Invalid(String),
    #[error("webhook_url is not allowed: {0}")]
    NotAllowed(String),
}

/// Loopback, private, link-local and other non-public addresses.
pub fn is_non_public(ip: IpAddr) -> bool {
    match ip {
        IpAddr::V4(v4) => {
            let o = v4.octets();
            v4.is_private()
                || v4.is_loopback()
                || v4.is_link_local()
                || v4.is_unspecified()
                || v4.is_broadcast()
                || v4.is_multicast()
                || v4.is_documentation()
                || o[0] == 0
                || (o[0] == 100 && (64..128).contains(&o[1])) // shared address space
                || o[0] >= 240
        }
        IpAddr::V6(v6) => {
            if let Some(v4) = v6.to_ipv4_mapped() {
                return is_non_public(IpAddr::V4(v4));
            }
            let s = v6.segments();
            v6.is_loopback()
                || v6.is_unspecified()
                || v6.is_multicast()
                || (s[0] & 0xfe00) == 0xfc00 // unique local
                || (s[0] & 0xffc0) == 0xfe80 // link-local
                || s[0] == 0x2001 && s[1] == 0x0db8 // documentation
        }
    }
}

/// Check a webhook URL: http(s), and (unless `allow_private`) every address its host
/// resolves to is public.
pub async fn check_url(url: &str, allow_private: bool) -> Result<reqwest::Url, UrlRefusal> {
    let u = reqwest::Url::parse(url).map_err(|e| UrlRefusal::Invalid(e.to_string()))?;
    if !matches!(u.scheme(), "http" | "https") {
        return Err(UrlRefusal::Invalid(format!(
            "scheme {:?} (only http and https)",
            u.scheme()
        )));
    }
    let host = u
        .host_str()
        .ok_or_else(|| UrlRefusal::Invalid("no host".into()))?
        .to_string();
    if allow_private {
        return Ok(u);
    }
    let port = u.port_or_known_default().unwrap_or(80);
    let bare = host.trim_start_matches('[').trim_end_matches(']');
    let addrs: Vec<IpAddr> = match bare.parse::<IpAddr>() {
        Ok(ip) => vec![ip],
        Err(_) => tokio::net::lookup_host((bare, port))
            .await
            .map_err(|e| UrlRefusal::NotAllowed(format!("cannot resolve {host}: {e}")))?
            .map(|a| a.ip())
            .collect(),
    };
    if addrs.is_empty() {
        return Err(UrlRefusal::NotAllowed(format!("{host} has no address")));
    }
    if let Some(ip) = addrs.into_iter().find(|ip| is_non_public(*ip)) {
        return Err(UrlRefusal::NotAllowed(format!(
            "{host} is a loopback or private address ({ip}); set webhook_allow_private = true for closed networks"
        )));
    }
    Ok(u)
}

/// `v1,<base64 HMAC-SHA256 of "id.timestamp.body">` (Standard Webhooks).
pub fn sign(key: &[u8], msg_id: &str, timestamp: i64, body: &[u8]) -> String {
    let mut mac = match Hmac::<Sha256>::new_from_slice(key) {
        Ok(m) => m,
        Err(_) => unreachable!("HMAC accepts keys of any length"),
    };
    mac.update(msg_id.as_bytes());
    mac.update(b".");
    mac.update(timestamp.to_string().as_bytes());
    mac.update(b".");
    mac.update(body);
    format!(
        "v1,{}",
        base64::engine::general_purpose::STANDARD.encode(mac.finalize().into_bytes())
    )
}

/// Delay before attempt `n + 1` after `n` failed attempts: 2 s, 10 s, 50 s, ... at most 4 h.
pub fn backoff(failed_attempts: i64) -> Duration {
    let n = failed_attempts.clamp(1, 12) as u32 - 1;
    Duration::from_secs((2u64 * 5u64.pow(n)).min(4 * 3600))
}

/// The body sent: the job as listed by the API (without its trace).
pub fn payload(j: &JobRecord) -> Vec<u8> {
    let v = serde_json::json!({
        "id": j.id, "scene_id": j.scene_id, "query": j.query, "status": j.status,
        "attempts": j.attempts, "created_at": j.created_at, "started_at": j.started_at,
        "finished_at": j.finished_at, "error": j.error, "result": j.result,
    });
    serde_json::to_vec(&v).unwrap_or_default()
}

/// Delivers due webhooks until `stop` is cancelled.
pub struct Dispatcher {
    pub store: Store,
    pub allow_private: bool,
    pub client: reqwest::Client,
}

impl Dispatcher {
    pub fn new(store: Store, allow_private: bool) -> anyhow::Result<Self> {
        let client = reqwest::Client::builder()
            .timeout(Duration::from_secs(15))
            .redirect(reqwest::redirect::Policy::none())
            .build()?;
        Ok(Self {
            store,
            allow_private,
            client,
        })
    }

    pub async fn run(self, stop: CancellationToken) {
        loop {
            match self.store.due_webhooks(16).await {
                Ok(due) => {
                    let n = due.len();
                    futures::future::join_all(due.into_iter().map(|d| self.deliver(d))).await;
                    if n == 16 {
                        continue;
                    }
                }
                Err(e) => tracing::error!("webhooks: cannot read the queue: {e}"),
            }
            let next = self.store.next_webhook_due().await.ok().flatten();
            let wait = next.map(|t| (t - now_ms()).clamp(0, 250)).unwrap_or(250);
            tokio::select! {
                _ = stop.cancelled() => return,
                _ = tokio::time::sleep(Duration::from_millis(wait as u64)) => {}
            }
        }
    }

    async fn deliver(&self, d: DueWebhook) {
        let (status, error) = match self.attempt(&d).await {
            Ok(s) if (200..300).contains(&s) => (Some(s), None),
            Ok(s) => (Some(s), Some(format!("the receiver answered {s}"))),
            Err(e) => (None, Some(e)),
        };
        let delivered = error.is_none();
        let retry_at = now_ms() + backoff(d.attempts + 1).as_millis() as i64;
        let retry_at_ms =
            (!delivered && retry_at - d.first_at_ms <= GIVE_UP_AFTER_MS).then_some(retry_at);
        let a = Attempt {
            status,
            error: error.as_deref(),
            retry_at_ms,
            delivered,
        };
        if let Err(e) = self.store.record_webhook_attempt(&d.job_id, &a).await {
            tracing::error!(job = %d.job_id, "webhooks: cannot record an attempt: {e}");
        }
    }

    /// One POST; the receiver's status, or why there was none.
    async fn attempt(&self, d: &DueWebhook) -> Result<u16, String> {
        let job = self
            .store
            .get_job(&d.job_id)
            .await
            .map_err(|e| e.to_string())?
            .ok_or("the job no longer exists")?;
        let url = job
            .webhook_url
            .as_deref()
            .ok_or("the job has no webhook_url")?;
        let url = check_url(url, self.allow_private)
            .await
            .map_err(|e| e.to_string())?;
        let owner = job.owner.ok_or("the job has no key to sign with")?;
        let key = self
            .store
            .webhook_key_bytes(owner)
            .await
            .map_err(|e| e.to_string())?
            .ok_or("the job's key no longer exists")?;
        let body = payload(&job);
        let ts = time::OffsetDateTime::now_utc().unix_timestamp();
        let sig = sign(&key, &d.msg_id, ts, &body);
        let resp = self
            .client
            .post(url)
            .header("content-type", "application/json")
            .header("webhook-id", &d.msg_id)
            .header("webhook-timestamp", ts.to_string())
            .header("webhook-signature", sig)
            .body(body)
            .send()
            .await
            .map_err(|e| format!("no answer: {e}"))?;
        Ok(resp.status().as_u16())
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn non_public_addresses_are_recognised() {
        for ip in [
            "127.0.0.1",
            "10.1.2.3",
            "192.168.0.5",
            "172.16.0.1",
            "169.254.169.254",
            "100.64.0.1",
            "0.0.0.0",
            "::1",
            "fd00::1",
            "fe80::1",
            "::ffff:127.0.0.1",
        ] {
            assert!(is_non_public(ip.parse().unwrap()), "{ip}");
        }
        for ip in ["8.8.8.8", "1.1.1.1", "2606:4700::1111"] {
            assert!(!is_non_public(ip.parse().unwrap()), "{ip}");
        }
    }

    #[tokio::test]
    async fn urls_are_checked_for_scheme_and_address() {
        assert!(matches!(
            check_url("ftp://example.com/x", false).await,
            Err(UrlRefusal::Invalid(_))
        ));
        assert!(matches!(
            check_url("http://127.0.0.1:9/hook", false).await,
            Err(UrlRefusal::NotAllowed(_))
        ));
        assert!(matches!(
            check_url("http://[::1]/hook", false).await,
            Err(UrlRefusal::NotAllowed(_))
        ));
        assert!(check_url("http://127.0.0.1:9/hook", true).await.is_ok());
        assert!(check_url("https://93.184.215.14/hook", false).await.is_ok());
    }

    #[test]
    fn signature_matches_a_known_vector() {
        // Standard Webhooks' published example secret, message id and timestamp.
        let key = base64::engine::general_purpose::STANDARD
            .decode("MfKQ9r8GKYqrTwjUPD8ILPZIo2LaLaSw")
            .unwrap();
        let body = br#"{"test": 2432232314}"#;
        assert_eq!(
            sign(&key, "msg_p5jXN8AQM9LWM0D4loKWxJek", 1614265330, body),
            "v1,g0hM9SsE+OTPJTGt/tmIKtSyZlE3uFJELVlNIOLJ1OE="
        );
    }

    #[test]
    fn backoff_grows_and_the_first_retry_is_within_ten_seconds() {
        assert!(backoff(1) <= Duration::from_secs(10));
        assert!(backoff(2) > backoff(1));
        assert_eq!(backoff(40), Duration::from_secs(4 * 3600));
    }
}

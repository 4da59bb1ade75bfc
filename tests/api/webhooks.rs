//! Issue 19: webhooks signed per Standard Webhooks, retried until the receiver accepts.

use crate::helpers::*;
use axum::http::{HeaderMap, StatusCode};
use base64::Engine;
use hmac::{Hmac, Mac};
use serde_json::{json, Value};
use sha2::Sha256;
use std::sync::{Arc, Mutex};
use std::time::Duration;

type Received = Arc<Mutex<Vec<(HeaderMap, Vec<u8>)>>>;

/// A receiver that answers 500 to the first delivery and 200 afterwards.
async fn receiver() -> (String, Received) {
    let got: Received = Default::default();
    let g = got.clone();
    let app = axum::Router::new().route(
        "/hook",
        axum::routing::post(move |headers: HeaderMap, body: axum::body::Bytes| {
            let g = g.clone();
            async move {
                let mut v = g.lock().unwrap();
                v.push((headers, body.to_vec()));
                if v.len() == 1 {
                    StatusCode::INTERNAL_SERVER_ERROR
                } else {
                    StatusCode::OK
                }
            }
        }),
    );
    let l = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = l.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(l, app).await.unwrap() });
    (format!("http://{addr}/hook"), got)
}

fn verify(whsec: &str, headers: &HeaderMap, body: &[u8]) -> bool {
    let key = base64::engine::general_purpose::STANDARD
        .decode(whsec.strip_prefix("whsec_").unwrap())
        .unwrap();
    let h = |n: &str| headers[n].to_str().unwrap().to_string();
    let mut mac = Hmac::<Sha256>::new_from_slice(&key).unwrap();
    mac.update(format!("{}.{}.", h("webhook-id"), h("webhook-timestamp")).as_bytes());
    mac.update(body);
    let want = format!(
        "v1,{}",
        base64::engine::general_purpose::STANDARD.encode(mac.finalize().into_bytes())
    );
    h("webhook-signature").split(' ').any(|s| s == want)
}

#[tokio::test]
async fn a_failed_delivery_is_retried_and_both_attempts_are_listed() {
    let dir = tempfile::tempdir().unwrap();
    let (secret, whsec) = create_key(dir.path(), "robot", false, None, None).await;
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.webhook_allow_private = true;
    let app = TestApp::spawn_with(cfg).await;
    let c = client_with_key(&secret);
    let (url, got) = receiver().await;
    let sid = upload_tiny_scene_to(&c, &app.url(""), 3).await;
    let r = c
        .post(app.url("/v1/jobs"))
        .json(&json!({"scene_id": sid, "query": "the lamp", "webhook_url": url}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 202);
    let j: Value = r.json().await.unwrap();
    assert_eq!(j["webhook"]["url"], url.as_str());
    let path = app.url(&format!("/v1/jobs/{}", j["id"].as_str().unwrap()));

    // Wait for the second attempt (the first retry comes within 10 s).
    let mut job = Value::Null;
    for _ in 0..150 {
        job = c.get(&path).send().await.unwrap().json().await.unwrap();
        if job["webhook"]["deliveries"]
            .as_array()
            .map_or(0, |d| d.len())
            >= 2
        {
            break;
        }
        tokio::time::sleep(Duration::from_millis(100)).await;
    }
    let d = job["webhook"]["deliveries"].as_array().unwrap();
    assert_eq!(d.len(), 2, "{job}");
    assert_eq!(d[0]["status"], 500);
    assert!(d[0]["error"].as_str().unwrap().contains("500"));
    assert_eq!(d[1]["status"], 200);
    assert!(d[1]["error"].is_null());
    assert_eq!(job["webhook"]["state"], "delivered");

    let got = got.lock().unwrap().clone();
    assert_eq!(got.len(), 2);
    for (h, body) in got.iter() {
        assert!(verify(&whsec, h, body), "signature verifies");
        assert!(
            !verify("whsec_AAAA", h, body),
            "and a wrong secret does not"
        );
        let sent: Value = serde_json::from_slice(body).unwrap();
        assert_eq!(sent["id"], j["id"]);
        assert_eq!(sent["status"], "succeeded");
        assert!(sent["result"]["box"].is_object());
    }
    assert_eq!(
        got[0].0["webhook-id"], got[1].0["webhook-id"],
        "one message id"
    );
    app.stop().await;
}

#[tokio::test]
async fn private_and_loopback_webhook_urls_are_refused_by_default() {
    let dir = tempfile::tempdir().unwrap();
    let (secret, _) = create_key(dir.path(), "robot", false, None, None).await;
    let app = TestApp::spawn_with(test_config(dir.path().to_path_buf())).await;
    let c = client_with_key(&secret);
    let sid = upload_tiny_scene_to(&c, &app.url(""), 3).await;
    for (url, code) in [
        ("http://127.0.0.1:9/hook", "webhook_url_not_allowed"),
        ("http://10.0.0.7/hook", "webhook_url_not_allowed"),
        ("http://[::1]:80/hook", "webhook_url_not_allowed"),
        ("http://localhost/hook", "webhook_url_not_allowed"),
        ("ftp://example.com/x", "invalid_webhook_url"),
    ] {
        let r = c
            .post(app.url("/v1/jobs"))
            .json(&json!({"scene_id": sid, "query": "q", "webhook_url": url}))
            .send()
            .await
            .unwrap();
        assert_eq!(r.status().as_u16(), 422, "{url}");
        assert_eq!(r.json::<Value>().await.unwrap()["code"], code, "{url}");
    }
    app.stop().await;
}

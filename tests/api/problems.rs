//! Every 4xx is problem+json, including the rejections of axum's own extractors and
//! router (query, path, JSON, content type, method).

use crate::helpers::TestApp;
use serde_json::Value;

async fn assert_problem(resp: reqwest::Response, status: u16, code: &str) -> Value {
    assert_eq!(resp.status().as_u16(), status);
    let ct = resp.headers()["content-type"].to_str().unwrap().to_string();
    assert!(ct.starts_with("application/problem+json"), "{ct}");
    let body: Value = resp.json().await.unwrap();
    assert_eq!(body["status"], status, "{body}");
    assert_eq!(body["code"], code, "{body}");
    assert!(!body["detail"].as_str().unwrap().is_empty(), "{body}");
    body
}

#[tokio::test]
async fn extractor_and_router_rejections_are_problems() {
    let app = TestApp::spawn().await;
    let http = &app.client;
    // Query string that does not deserialize, and one out of range.
    let r = http
        .get(app.url("/v1/jobs?limit=abc"))
        .send()
        .await
        .unwrap();
    assert_problem(r, 400, "invalid_query_string").await;
    let r = http
        .get(app.url("/v1/jobs?limit=99999999999999999999"))
        .send()
        .await
        .unwrap();
    assert_problem(r, 400, "invalid_query_string").await;
    let r = http
        .get(app.url("/v1/jobs?limit=501"))
        .send()
        .await
        .unwrap();
    assert_problem(r, 400, "invalid_limit").await;
    // A body that is not JSON by its content type.
    let r = http
        .post(app.url("/v1/jobs"))
        .header("content-type", "text/plain")
        .body("{}")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 415);
    assert!(r.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("application/problem+json"));
    // JSON of the wrong shape.
    let r = http
        .post(app.url("/v1/jobs"))
        .json(&serde_json::json!({"scene_id": 5}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status().as_u16(), 422);
    assert!(r.headers()["content-type"]
        .to_str()
        .unwrap()
        .starts_with("application/problem+json"));
    // A method the route does not have keeps its Allow header.
    let r = http.delete(app.url("/healthz")).send().await.unwrap();
    let allow = r
        .headers()
        .get("allow")
        .map(|v| v.to_str().unwrap().to_string());
    assert_problem(r, 405, "method_not_allowed").await;
    assert!(allow.unwrap_or_default().contains("GET"));
}

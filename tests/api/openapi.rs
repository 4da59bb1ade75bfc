/// The checked-in openapi.yaml is exactly what the code generates.
/// Regenerate with `cargo run -- openapi > openapi.yaml`.
#[test]
fn checked_in_openapi_matches_the_code() {
    let generated = grounder::api::openapi::yaml();
    let path = std::path::Path::new(env!("CARGO_MANIFEST_DIR")).join("openapi.yaml");
    let on_disk = std::fs::read_to_string(&path).unwrap_or_default();
    assert!(generated.contains("/v1/jobs/{id}/cancel"));
    assert!(
        on_disk == generated,
        "openapi.yaml is stale: run `cargo run -- openapi > openapi.yaml`"
    );
}

/// The example of an archive upload is a body the server answers as the document says:
/// a tar without a scene, refused 422 `no_scene` (a documented status of the route).
#[tokio::test]
async fn the_upload_example_is_answered_as_documented() {
    use utoipa::OpenApi;
    let doc = serde_json::to_value(grounder::api::openapi::ApiDoc::openapi()).expect("json");
    let post = &doc["paths"]["/v1/scenes"]["post"];
    let example = post["requestBody"]["content"]["application/octet-stream"]["example"]
        .as_str()
        .expect("an example archive");
    assert!(post["responses"]["422"].is_object(), "422 is documented");
    let app = crate::helpers::TestApp::spawn().await;
    let r = app
        .upload(example.as_bytes().to_vec(), "application/octet-stream")
        .await;
    assert_eq!(r.status().as_u16(), 422);
    let p: serde_json::Value = r.json().await.expect("problem");
    assert_eq!(p["code"], "no_scene", "{p}");
    app.stop().await;
}

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

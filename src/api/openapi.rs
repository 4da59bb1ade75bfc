//! The OpenAPI document, generated from the handlers and types (checked in as openapi.yaml).

use axum::http::header;
use axum::response::IntoResponse;
use utoipa::OpenApi;

#[derive(OpenApi)]
#[openapi(
    info(title = "grounder", description = "Find the object a sentence describes in a scanned room and return its 3D box."),
    paths(
        super::scenes::upload, super::scenes::list, super::scenes::get, super::scenes::delete, super::scenes::reindex,
        super::jobs::create, super::jobs::list, super::jobs::get, super::jobs::cancel, super::jobs::artifact,
        super::exports::object_ply, super::exports::mask_png, super::exports::scene_points, super::exports::scene_frames, super::exports::frame_jpeg,
        super::viewer::job_page, super::viewer::scene_page, super::viewer::asset,
        super::health::healthz, super::health::readyz, super::health::metrics,
    ),
    components(schemas(super::Problem, crate::store::SceneRecord, crate::store::scenes::IndexProgress, super::scenes::SceneList,
        super::jobs::Job, super::jobs::JobList, super::jobs::CreateJob, crate::store::JobStatus, super::health::Health,
        super::exports::FrameList, crate::jobs::exports::FrameInfo)),
    tags((name = "scenes", description = "Posed RGB-D scenes"), (name = "jobs", description = "Grounding jobs"), (name = "exports", description = "3D points, masks and frames for viewers and robots"), (name = "viewer", description = "HTML pages to inspect scenes and jobs"), (name = "health", description = "Operations"))
)]
pub struct ApiDoc;

/// The document as YAML.
pub fn yaml() -> String {
    let mut doc = ApiDoc::openapi();
    doc.info.version = env!("CARGO_PKG_VERSION").to_string();
    doc.to_yaml().unwrap_or_default()
}

pub async fn serve_yaml() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "application/yaml")], yaml())
}

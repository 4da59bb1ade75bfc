//! The OpenAPI document, generated from the handlers and types (checked in as openapi.yaml).

use axum::http::header;
use axum::response::IntoResponse;
use utoipa::OpenApi;

#[derive(OpenApi)]
#[openapi(
    info(title = "grounder", description = "Find the object a sentence describes in a scanned room and return its 3D box."),
    paths(
        super::scenes::upload, super::scenes::list, super::scenes::get, super::scenes::delete, super::scenes::reindex, super::frames::append, super::frames::remove,
        super::jobs::create, super::jobs::list, super::jobs::get, super::events::events, super::jobs::cancel, super::jobs::artifact,
        super::exports::object_ply, super::exports::mask_png, super::exports::scene_points, super::exports::scene_frames, super::exports::frame_jpeg,
        super::viewer::job_page, super::viewer::scene_page, super::viewer::asset,
        super::health::healthz, super::health::readyz, super::health::metrics,
    ),
    components(schemas(super::Problem, crate::store::SceneRecord, crate::store::scenes::IndexProgress, super::scenes::SceneList,
        super::jobs::Job, super::jobs::JobList, super::jobs::CreateJob, super::jobs::JobBatch, super::jobs::Created,
        super::jobs::WebhookInfo, crate::store::webhooks::Delivery, crate::store::JobStatus, super::health::Health,
        super::exports::FrameList, crate::jobs::exports::FrameInfo)),
    modifiers(&BearerAuth),
    tags((name = "scenes", description = "Posed RGB-D scenes"), (name = "jobs", description = "Grounding jobs"), (name = "exports", description = "3D points, masks and frames for viewers and robots"), (name = "viewer", description = "HTML pages to inspect scenes and jobs"), (name = "health", description = "Operations"))
)]
pub struct ApiDoc;

/// The `bearer` security scheme: `Authorization: Bearer gk_...` (required once keys exist).
struct BearerAuth;

impl utoipa::Modify for BearerAuth {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::security::{HttpAuthScheme, HttpBuilder, SecurityScheme};
        let components = openapi.components.get_or_insert_with(Default::default);
        components.add_security_scheme(
            "bearer",
            SecurityScheme::Http(
                HttpBuilder::new()
                    .scheme(HttpAuthScheme::Bearer)
                    .description(Some("An API key from `grounder keys create`. Needed for every /v1/ request once a key exists; /metrics then needs an admin key."))
                    .build(),
            ),
        );
    }
}

/// The document as YAML.
pub fn yaml() -> String {
    let mut doc = ApiDoc::openapi();
    doc.info.version = env!("CARGO_PKG_VERSION").to_string();
    doc.to_yaml().unwrap_or_default()
}

pub async fn serve_yaml() -> impl IntoResponse {
    ([(header::CONTENT_TYPE, "application/yaml")], yaml())
}

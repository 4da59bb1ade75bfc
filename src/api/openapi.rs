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
    modifiers(&BearerAuth, &BinaryUploads),
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

/// Upload bodies are bytes (`type: string, format: binary`) in every media type the
/// server reads: tar, gzip, zip, and `application/octet-stream` (a raw `.sens`, or an
/// archive recognised by its first bytes), so that clients and generators can build them.
struct BinaryUploads;

impl utoipa::Modify for BinaryUploads {
    fn modify(&self, openapi: &mut utoipa::openapi::OpenApi) {
        use utoipa::openapi::content::Content;
        use utoipa::openapi::schema::{KnownFormat, ObjectBuilder, SchemaFormat, Type};
        for path in ["/v1/scenes", "/v1/scenes/{id}/frames"] {
            let Some(body) = openapi
                .paths
                .paths
                .get_mut(path)
                .and_then(|item| item.post.as_mut())
                .and_then(|op| op.request_body.as_mut())
            else {
                continue;
            };
            body.content.clear();
            for media in [
                "application/x-tar",
                "application/gzip",
                "application/zip",
                "application/octet-stream",
            ] {
                let schema = ObjectBuilder::new()
                    .schema_type(Type::String)
                    .format(Some(SchemaFormat::KnownFormat(KnownFormat::Binary)))
                    .build();
                let mut content = Content::new(Some(schema));
                if path == "/v1/scenes" && media == "application/octet-stream" {
                    content.example = upload_example();
                }
                body.content.insert(media.to_string(), content);
            }
        }
    }
}

/// The example of an archive upload (on `application/octet-stream`, which generic clients
/// can send as bytes; the tar is recognised by its first bytes): a tar (all ASCII, so that it can stand in the YAML)
/// holding only `scene/README.txt`. The server unpacks it and answers 422 `no_scene`, as
/// documented: a real scene carries JPEG and PNG frames, which no text example can.
fn upload_example() -> Option<serde_json::Value> {
    let text = b"A scene archive holds color/, depth/, pose/ and intrinsic/ (FORMATS.md).\n";
    let mut b = tar::Builder::new(Vec::new());
    let mut h = tar::Header::new_ustar();
    h.set_path("scene/README.txt").ok()?;
    h.set_size(text.len() as u64);
    h.set_mode(0o644);
    h.set_mtime(0);
    h.set_cksum();
    b.append(&h, &text[..]).ok()?;
    let bytes = b.into_inner().ok()?;
    String::from_utf8(bytes).ok().map(serde_json::Value::String)
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

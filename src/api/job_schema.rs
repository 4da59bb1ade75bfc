//! The OpenAPI schema of a job request (`CreateJob`): written by hand, since the derive
//! cannot say that exactly one of `query` and `queries` is given.

impl utoipa::PartialSchema for super::jobs::CreateJob {
    fn schema() -> utoipa::openapi::RefOr<utoipa::openapi::schema::Schema> {
        create_job_schema().into()
    }
}

impl utoipa::ToSchema for super::jobs::CreateJob {}

/// A character `str::trim` keeps: the pattern of a description that is not blank (JSON
/// Schema's `\S` differs from Rust's whitespace in U+0085 and U+FEFF).
const NOT_BLANK: &str =
    "[^\\t-\\r \\u0085\\u00a0\\u1680\\u2000-\\u200a\\u2028\\u2029\\u202f\\u205f\\u3000]";

/// `CreateJob` as a contract: one of two objects, `{scene_id, query}` or `{scene_id,
/// queries}` (the other key absent or null), each with an optional `webhook_url` and
/// nothing else; every description not blank and at most 2000 characters.
fn create_job_schema() -> utoipa::openapi::schema::Schema {
    use utoipa::openapi::schema::{
        AdditionalProperties, ArrayBuilder, ObjectBuilder, OneOfBuilder, Schema, Type,
    };
    let description = |text: &str| {
        ObjectBuilder::new()
            .schema_type(Type::String)
            .min_length(Some(1))
            .max_length(Some(super::jobs::MAX_QUERY_CHARS))
            .pattern(Some(NOT_BLANK))
            .description(Some(text))
    };
    let variant = |title: &str, key: &str, value: Schema, other: &str| {
        ObjectBuilder::new()
            .title(Some(title))
            .property(
                "scene_id",
                ObjectBuilder::new()
                    .schema_type(Type::String)
                    .description(Some("The scene to search")),
            )
            .required("scene_id")
            .property(key, value)
            .required(key)
            .property(
                other,
                ObjectBuilder::new()
                    .schema_type(Type::Null)
                    .description(Some("Absent or null")),
            )
            .property(
                "webhook_url",
                ObjectBuilder::new()
                    .schema_type(utoipa::openapi::schema::SchemaType::from_iter([
                        Type::String,
                        Type::Null,
                    ]))
                    .description(Some(
                        "http(s) URL POSTed the job (signed per Standard Webhooks) when it ends; needs an API key.",
                    )),
            )
            .additional_properties(Some(AdditionalProperties::FreeForm(false)))
            .build()
    };
    let one = variant(
        "One job",
        "query",
        description(
            "The description of the object, e.g. \"the black chair next to the window\" (not blank, at most 2000 characters).",
        )
        .build()
        .into(),
        "queries",
    );
    let batch = variant(
        "One job per query",
        "queries",
        ArrayBuilder::new()
            .items(description(
                "One description (not blank, at most 2000 characters).",
            ))
            .min_items(Some(1))
            .max_items(Some(super::jobs::MAX_BATCH))
            .description(Some(
                "Several descriptions at once (1 to 100); one job each, in this order.",
            ))
            .build()
            .into(),
        "query",
    );
    OneOfBuilder::new()
        .item(one)
        .item(batch)
        .description(Some(
            "`query` for one job, or `queries` for one job per query (answered as `{\"jobs\": [...]}`).",
        ))
        .build()
        .into()
}

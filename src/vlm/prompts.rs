//! Prompt templates: plain-text files in `prompts/` with `{name}` placeholders.
//!
//! The defaults are compiled in; [`Prompts::load`] with a directory replaces any template
//! whose file exists there. Every template is checked at load time: it may only use the
//! placeholders its kind allows, and every render fills all of them.
//!
//! Each task/feedback template starts with a marker line (see [`markers`]) so that a reader
//! of a conversation (the oracle VLM, a trace viewer) can tell which prompt it is.

pub use super::boxes::BoxFormat;
use std::collections::BTreeSet;
use std::path::Path;

/// The marker lines the default templates start with. An overriding template should keep
/// its marker line, or the oracle VLM will not recognise it.
pub mod markers {
    /// Query analysis request.
    pub const QUERY_ANALYSIS: &str = "Task: query analysis";
    /// Grounding request (pick an image).
    pub const GROUNDING: &str = "Task: image selection";
    /// Instance selection request (pick an object id).
    pub const INSTANCE: &str = "Task: object selection";
    /// Feedback: the chosen image id does not exist.
    pub const IMAGE_INVALID: &str = "Feedback: image id not valid";
    /// Feedback: no detection of the target class in the chosen image.
    pub const OBJECT_NOT_EXISTING: &str = "Feedback: no target in image";
    /// Feedback: the chosen object id does not exist.
    pub const OBJECT_ID_INVALID: &str = "Feedback: object id not valid";
    /// Feedback: the box chosen in the image has almost no depth reading.
    pub const NO_DEPTH: &str = "Feedback: target not measured";
    /// In that feedback, the line that lists the frames which measured the place (the
    /// prefix of the line; the ids follow it).
    pub const MEASURED_BY: &str = "Frames that measured it:";
    /// Feedback: the reply could not be parsed.
    pub const UNPARSABLE: &str = "Feedback: reply not readable";
    /// Set-of-marks selection request (pick a marked region's id).
    pub const MARKS: &str = "Task: mark selection";
    /// Request for the target's 2D box (`detector = "vlm"`).
    pub const BOX: &str = "Task: object box";
    /// Feedback: the box is outside the frame, degenerate or unreadable.
    pub const BOX_INVALID: &str = "Feedback: box not valid";
}

mod kind;
pub use kind::TemplateKind;

/// Errors while loading templates.
#[derive(Debug, thiserror::Error)]
pub enum PromptError {
    /// A template file exists but cannot be read.
    #[error("cannot read prompt template {path}: {source}")]
    Read {
        /// File path.
        path: String,
        /// Cause.
        source: std::io::Error,
    },
    /// A template uses a placeholder its kind does not provide.
    #[error("prompt template {file} uses unknown placeholder {{{name}}}")]
    UnknownPlaceholder {
        /// Template file name.
        file: &'static str,
        /// Placeholder name.
        name: String,
    },
    /// The prompts path is not a directory.
    #[error("prompts path {0} is not a directory")]
    NotADirectory(String),
}

/// Names of all `{name}` placeholders in a template (name = lowercase ASCII, digits, `_`).
pub fn placeholders_in(template: &str) -> BTreeSet<String> {
    let mut out = BTreeSet::new();
    let bytes = template.as_bytes();
    let mut i = 0;
    while i < bytes.len() {
        if bytes[i] == b'{' {
            let start = i + 1;
            let mut j = start;
            while j < bytes.len()
                && (bytes[j].is_ascii_lowercase() || bytes[j].is_ascii_digit() || bytes[j] == b'_')
            {
                j += 1;
            }
            if j > start && j < bytes.len() && bytes[j] == b'}' && bytes[start].is_ascii_lowercase()
            {
                out.insert(template[start..j].to_string());
                i = j + 1;
                continue;
            }
        }
        i += 1;
    }
    out
}

/// Replace each `{name}` by its value, in one pass (values are never re-scanned).
fn fill(template: &str, vars: &[(&str, String)]) -> String {
    let mut out = String::with_capacity(template.len() + 256);
    let mut rest = template;
    while let Some(pos) = rest.find('{') {
        out.push_str(&rest[..pos]);
        let tail = &rest[pos..];
        let hit = vars.iter().find(|(name, _)| {
            tail.len() > name.len() + 1
                && tail[1..].starts_with(name)
                && tail.as_bytes()[name.len() + 1] == b'}'
        });
        match hit {
            Some((name, value)) => {
                out.push_str(value);
                rest = &tail[name.len() + 2..];
            }
            None => {
                out.push('{');
                rest = &tail[1..];
            }
        }
    }
    out.push_str(rest);
    out
}

/// Five-digit image id as shown on the tiles, e.g. `7` → `"00007"`.
pub fn format_image_id(id: u32) -> String {
    format!("{id:05}")
}

fn join_ids(ids: &[u32]) -> String {
    ids.iter()
        .map(|&i| format_image_id(i))
        .collect::<Vec<_>>()
        .join(", ")
}

fn list_or_none(items: &[String]) -> String {
    if items.is_empty() {
        "none".to_string()
    } else {
        items.join("; ")
    }
}

/// What the grounding user message needs.
#[derive(Debug, Clone)]
pub struct GroundingInput<'a> {
    /// The user's sentence.
    pub query: &'a str,
    /// Target class from query analysis.
    pub target_class: &'a str,
    /// Attributes from query analysis.
    pub attributes: &'a [String],
    /// Conditions from query analysis.
    pub conditions: &'a [String],
    /// Image ids shown in the grids, in order.
    pub image_ids: &'a [u32],
    /// Number of grid images attached.
    pub num_grids: usize,
}

/// What the instance-selection message needs.
#[derive(Debug, Clone)]
pub struct InstanceInput<'a> {
    /// The user's sentence.
    pub query: &'a str,
    /// Target class from query analysis.
    pub target_class: &'a str,
    /// Image id of the chosen frame.
    pub image_id: u32,
    /// Frame width in pixels (the coordinate system of the boxes).
    pub width: u32,
    /// Frame height in pixels.
    pub height: u32,
    /// Candidate boxes `[x1, y1, x2, y2]`; the object id is the index.
    pub candidates: &'a [[f32; 4]],
}

/// Which reply was expected, for the unparsable-reply feedback.
#[derive(Debug, Clone, Copy, PartialEq, Eq)]
pub enum ReplyKind {
    /// Query analysis reply.
    QueryAnalysis,
    /// Grounding reply.
    Grounding,
    /// Instance selection reply.
    Instance,
    /// Box request reply.
    Box,
}

/// The loaded templates.
#[derive(Debug, Clone)]
pub struct Prompts {
    templates: Vec<(TemplateKind, String)>,
}

impl Prompts {
    /// The compiled-in templates.
    pub fn embedded() -> Self {
        let templates = TemplateKind::ALL
            .iter()
            .map(|&k| (k, k.embedded().to_string()))
            .collect();
        Self { templates }
    }

    /// Load templates: the embedded defaults, each replaced by `<dir>/<file name>` when `dir`
    /// is given and that file exists. Fails on unreadable files and unknown placeholders.
    pub fn load(dir: Option<&Path>) -> Result<Self, PromptError> {
        let mut p = Self::embedded();
        if let Some(dir) = dir {
            if !dir.is_dir() {
                return Err(PromptError::NotADirectory(dir.display().to_string()));
            }
            for (kind, text) in p.templates.iter_mut() {
                let path = dir.join(kind.file_name());
                if path.exists() {
                    *text = std::fs::read_to_string(&path).map_err(|source| PromptError::Read {
                        path: path.display().to_string(),
                        source,
                    })?;
                }
            }
        }
        p.validate()?;
        Ok(p)
    }

    fn validate(&self) -> Result<(), PromptError> {
        for (kind, text) in &self.templates {
            for name in placeholders_in(text) {
                if !kind.placeholders().contains(&name.as_str()) {
                    return Err(PromptError::UnknownPlaceholder {
                        file: kind.file_name(),
                        name,
                    });
                }
            }
        }
        Ok(())
    }

    /// The raw template text of one kind.
    pub fn template(&self, kind: TemplateKind) -> &str {
        self.templates
            .iter()
            .find(|(k, _)| *k == kind)
            .map(|(_, t)| t.as_str())
            .unwrap_or_else(|| kind.embedded())
    }

    /// Render a template with the given variables (must be exactly the kind's placeholders).
    pub fn render(&self, kind: TemplateKind, vars: &[(&str, String)]) -> String {
        fill(self.template(kind), vars)
    }

    /// Query analysis request.
    pub fn query_analysis(&self, query: &str) -> String {
        self.render(TemplateKind::QueryAnalysis, &[("query", one_line(query))])
    }

    /// System prompt of the grounding conversation.
    pub fn grounding_system(&self) -> String {
        self.render(TemplateKind::GroundingSystem, &[])
    }

    /// Grounding user message (attach the grids to the same message).
    pub fn grounding_input(&self, g: &GroundingInput<'_>) -> String {
        self.render(
            TemplateKind::GroundingInput,
            &[
                ("query", one_line(g.query)),
                ("target_class", one_line(g.target_class)),
                ("attributes", one_line(&list_or_none(g.attributes))),
                ("conditions", one_line(&list_or_none(g.conditions))),
                ("image_ids", join_ids(g.image_ids)),
                ("num_images", g.image_ids.len().to_string()),
                ("num_grids", g.num_grids.to_string()),
            ],
        )
    }

    /// Instance selection message (attach the annotated frame).
    pub fn instance_selection(&self, s: &InstanceInput<'_>) -> String {
        self.selection(TemplateKind::InstanceSelection, s)
    }

    /// Set-of-marks selection message (attach the frame with its marked regions).
    pub fn mark_selection(&self, s: &InstanceInput<'_>) -> String {
        self.selection(TemplateKind::MarkSelection, s)
    }

    fn selection(&self, kind: TemplateKind, s: &InstanceInput<'_>) -> String {
        let candidates = s
            .candidates
            .iter()
            .enumerate()
            .map(|(i, b)| {
                format!(
                    "ID {i}: box [{:.0}, {:.0}, {:.0}, {:.0}]",
                    b[0], b[1], b[2], b[3]
                )
            })
            .collect::<Vec<_>>()
            .join("\n");
        self.render(
            kind,
            &[
                ("query", one_line(s.query)),
                ("target_class", one_line(s.target_class)),
                ("image_id", format_image_id(s.image_id)),
                ("width", s.width.to_string()),
                ("height", s.height.to_string()),
                ("num_candidates", s.candidates.len().to_string()),
                ("candidates", candidates),
            ],
        )
    }

    /// Request for the target's box in frame `image_id` of `width` x `height` pixels, in
    /// the coordinates `format` names.
    pub fn box_request(
        &self,
        query: &str,
        target_class: &str,
        image_id: u32,
        (width, height): (u32, u32),
        format: BoxFormat,
    ) -> String {
        self.render(
            TemplateKind::BoxRequest,
            &[
                ("query", one_line(query)),
                ("target_class", one_line(target_class)),
                ("image_id", format_image_id(image_id)),
                ("width", width.to_string()),
                ("height", height.to_string()),
                ("box_format", format.name().to_string()),
                ("box_format_help", format.help(width, height)),
            ],
        )
    }

    /// Request for the whole target's box in frame `image_id` (`width` x `height` pixels),
    /// an ensemble view of the target that frame `anchor_id` saw in part; `part_box` is
    /// where that part falls in this frame, in pixels (stated in `format`).
    #[allow(clippy::too_many_arguments)]
    pub fn view_box_request(
        &self,
        query: &str,
        target_class: &str,
        image_id: u32,
        anchor_id: u32,
        (width, height): (u32, u32),
        part_box: [f32; 4],
        format: BoxFormat,
    ) -> String {
        let p = format.encode(part_box, (width, height));
        self.render(
            TemplateKind::ViewBoxRequest,
            &[
                ("query", one_line(query)),
                ("target_class", one_line(target_class)),
                ("image_id", format_image_id(image_id)),
                ("anchor_id", format_image_id(anchor_id)),
                ("width", width.to_string()),
                ("height", height.to_string()),
                (
                    "part_box",
                    format!("[{:.0}, {:.0}, {:.0}, {:.0}]", p[0], p[1], p[2], p[3]),
                ),
                ("box_format", format.name().to_string()),
                ("box_format_help", format.help(width, height)),
            ],
        )
    }

    /// Feedback: the box cannot be used, for `reason`.
    pub fn feedback_box_invalid(&self, reason: &str, format: BoxFormat) -> String {
        self.render(
            TemplateKind::FeedbackBoxInvalid,
            &[
                ("reason", one_line(reason)),
                ("box_format", format.name().to_string()),
            ],
        )
    }

    /// Feedback: `image_id` (as the VLM wrote it) is not among `valid_ids`.
    pub fn feedback_image_invalid(&self, image_id: &str, valid_ids: &[u32]) -> String {
        self.render(
            TemplateKind::FeedbackImageInvalid,
            &[
                ("image_id", one_line(image_id)),
                ("valid_ids", join_ids(valid_ids)),
            ],
        )
    }

    /// Feedback: no detection of `target_class` in image `image_id`.
    pub fn feedback_object_not_existing(&self, image_id: u32, target_class: &str) -> String {
        self.render(
            TemplateKind::FeedbackObjectNotExisting,
            &[
                ("image_id", format_image_id(image_id)),
                ("target_class", one_line(target_class)),
            ],
        )
    }

    /// Feedback: the box chosen in image `image_id` has almost no depth reading.
    pub fn feedback_no_depth(&self, image_id: u32, target_class: &str) -> String {
        self.render(
            TemplateKind::FeedbackNoDepth,
            &[
                ("image_id", format_image_id(image_id)),
                ("target_class", one_line(target_class)),
            ],
        )
    }

    /// Feedback: the box chosen in image `image_id` has almost no depth reading, and the
    /// frames `nearer` (best first) measured what it shows.
    pub fn feedback_no_depth_nearer(
        &self,
        image_id: u32,
        target_class: &str,
        nearer: &[u32],
    ) -> String {
        self.render(
            TemplateKind::FeedbackNoDepthNearer,
            &[
                ("image_id", format_image_id(image_id)),
                ("target_class", one_line(target_class)),
                ("image_ids", join_ids(nearer)),
            ],
        )
    }

    /// Feedback: `object_id` (as the VLM wrote it) is not one of `0..num_candidates`.
    pub fn feedback_object_id_invalid(&self, object_id: &str, num_candidates: usize) -> String {
        let valid = (0..num_candidates)
            .map(|i| i.to_string())
            .collect::<Vec<_>>()
            .join(", ");
        self.render(
            TemplateKind::FeedbackObjectIdInvalid,
            &[("object_id", one_line(object_id)), ("valid_ids", valid)],
        )
    }

    /// Feedback: the last reply could not be parsed as the expected JSON.
    pub fn feedback_unparsable(&self, kind: ReplyKind) -> String {
        let keys = match kind {
            ReplyKind::QueryAnalysis => r#""target_class", "attributes" and "conditions""#,
            ReplyKind::Grounding => r#""reasoning", "target_image_id" and "reference_image_ids""#,
            ReplyKind::Instance => r#""reasoning" and "object_id""#,
            ReplyKind::Box => r#""reasoning" and "bbox_2d""#,
        };
        self.render(
            TemplateKind::FeedbackUnparsable,
            &[("expected_keys", keys.to_string())],
        )
    }
}

/// Collapse newlines so a user-supplied value cannot forge a marker or data line.
fn one_line(s: &str) -> String {
    s.split_whitespace().collect::<Vec<_>>().join(" ")
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn finds_placeholders_but_not_json() {
        let p = placeholders_in(r#"a {query} {"k": 1} {x1} {} {Bad} {image_ids}"#);
        let v: Vec<_> = p.into_iter().collect();
        assert_eq!(v, vec!["image_ids", "query", "x1"]);
    }

    #[test]
    fn fill_does_not_rescan_values() {
        let s = fill("{a} and {b}", &[("a", "{b}".into()), ("b", "B".into())]);
        assert_eq!(s, "{b} and B");
    }
}

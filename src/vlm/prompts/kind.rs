//! The kinds of prompt template: file names, allowed placeholders, embedded defaults.

/// The kinds of template, with their file names and allowed placeholders.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Hash)]
pub enum TemplateKind {
    /// Query → {target_class, attributes, conditions}.
    QueryAnalysis,
    /// System prompt of the grounding conversation.
    GroundingSystem,
    /// Grounding user message (sent with the stitched grids).
    GroundingInput,
    /// Instance selection (sent with the annotated frame).
    InstanceSelection,
    /// Feedback: invalid image id.
    FeedbackImageInvalid,
    /// Feedback: no target-class detection in the chosen image.
    FeedbackObjectNotExisting,
    /// Feedback: invalid object id.
    FeedbackObjectIdInvalid,
    /// Feedback: reply could not be parsed.
    FeedbackUnparsable,
    /// Set-of-marks selection (sent with the frame and its marked candidates).
    MarkSelection,
    /// Request for the target's 2D box in the chosen frame.
    BoxRequest,
    /// Feedback: the box cannot be used.
    FeedbackBoxInvalid,
    /// Request for the whole target's box in an ensemble view, where the part the chosen
    /// frame saw is outlined.
    ViewBoxRequest,
    /// Feedback: the chosen box has almost no depth reading.
    FeedbackNoDepth,
    /// Feedback: the chosen box has almost no depth reading, and these frames measured
    /// what it shows.
    FeedbackNoDepthNearer,
}

impl TemplateKind {
    /// All kinds.
    pub const ALL: [TemplateKind; 14] = [
        Self::QueryAnalysis,
        Self::GroundingSystem,
        Self::GroundingInput,
        Self::InstanceSelection,
        Self::FeedbackImageInvalid,
        Self::FeedbackObjectNotExisting,
        Self::FeedbackObjectIdInvalid,
        Self::FeedbackUnparsable,
        Self::MarkSelection,
        Self::BoxRequest,
        Self::FeedbackBoxInvalid,
        Self::ViewBoxRequest,
        Self::FeedbackNoDepth,
        Self::FeedbackNoDepthNearer,
    ];

    /// File name inside the prompts directory.
    pub fn file_name(self) -> &'static str {
        match self {
            Self::QueryAnalysis => "query_analysis.txt",
            Self::GroundingSystem => "grounding_system.txt",
            Self::GroundingInput => "grounding_input.txt",
            Self::InstanceSelection => "instance_selection.txt",
            Self::FeedbackImageInvalid => "feedback_image_invalid.txt",
            Self::FeedbackObjectNotExisting => "feedback_object_not_existing.txt",
            Self::FeedbackObjectIdInvalid => "feedback_object_id_invalid.txt",
            Self::FeedbackUnparsable => "feedback_unparsable.txt",
            Self::MarkSelection => "mark_selection.txt",
            Self::BoxRequest => "box_request.txt",
            Self::FeedbackBoxInvalid => "feedback_box_invalid.txt",
            Self::ViewBoxRequest => "view_box_request.txt",
            Self::FeedbackNoDepth => "feedback_no_depth.txt",
            Self::FeedbackNoDepthNearer => "feedback_no_depth_nearer.txt",
        }
    }

    /// Placeholders this kind of template may use (the render function fills all of them).
    pub fn placeholders(self) -> &'static [&'static str] {
        match self {
            Self::QueryAnalysis => &["query"],
            Self::GroundingSystem => &[],
            Self::GroundingInput => &[
                "query",
                "target_class",
                "attributes",
                "conditions",
                "image_ids",
                "num_images",
                "num_grids",
            ],
            // Both show numbered candidates in one image and ask for one of them.
            Self::InstanceSelection | Self::MarkSelection => &[
                "query",
                "target_class",
                "image_id",
                "width",
                "height",
                "num_candidates",
                "candidates",
            ],
            Self::FeedbackImageInvalid => &["image_id", "valid_ids"],
            Self::FeedbackObjectNotExisting | Self::FeedbackNoDepth => {
                &["image_id", "target_class"]
            }
            Self::FeedbackNoDepthNearer => &["image_id", "target_class", "image_ids"],
            Self::FeedbackObjectIdInvalid => &["object_id", "valid_ids"],
            Self::FeedbackUnparsable => &["expected_keys"],
            Self::BoxRequest => &[
                "query",
                "target_class",
                "image_id",
                "width",
                "height",
                "box_format",
                "box_format_help",
            ],
            Self::FeedbackBoxInvalid => &["reason", "box_format"],
            Self::ViewBoxRequest => &[
                "query",
                "target_class",
                "image_id",
                "anchor_id",
                "width",
                "height",
                "part_box",
                "box_format",
                "box_format_help",
            ],
        }
    }

    pub(super) fn embedded(self) -> &'static str {
        match self {
            Self::QueryAnalysis => include_str!("../../../prompts/query_analysis.txt"),
            Self::GroundingSystem => include_str!("../../../prompts/grounding_system.txt"),
            Self::GroundingInput => include_str!("../../../prompts/grounding_input.txt"),
            Self::InstanceSelection => include_str!("../../../prompts/instance_selection.txt"),
            Self::FeedbackImageInvalid => {
                include_str!("../../../prompts/feedback_image_invalid.txt")
            }
            Self::FeedbackObjectNotExisting => {
                include_str!("../../../prompts/feedback_object_not_existing.txt")
            }
            Self::FeedbackObjectIdInvalid => {
                include_str!("../../../prompts/feedback_object_id_invalid.txt")
            }
            Self::FeedbackUnparsable => include_str!("../../../prompts/feedback_unparsable.txt"),
            Self::MarkSelection => include_str!("../../../prompts/mark_selection.txt"),
            Self::BoxRequest => include_str!("../../../prompts/box_request.txt"),
            Self::FeedbackBoxInvalid => include_str!("../../../prompts/feedback_box_invalid.txt"),
            Self::ViewBoxRequest => include_str!("../../../prompts/view_box_request.txt"),
            Self::FeedbackNoDepth => include_str!("../../../prompts/feedback_no_depth.txt"),
            Self::FeedbackNoDepthNearer => {
                include_str!("../../../prompts/feedback_no_depth_nearer.txt")
            }
        }
    }
}

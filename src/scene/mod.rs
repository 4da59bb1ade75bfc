//! Scenes: the FORMATS §1 layouts, safe archive import, validation, and the in-memory
//! scene the pipeline works on.

pub mod archive;
pub mod archive_guard;
pub mod depth_file;
pub mod format;
pub mod formats;
pub mod import;
pub mod model;
pub mod room;

pub use model::{FrameData, SceneData};
pub use room::RoomMemo;

/// Why a scene cannot be imported. Every variant names what is wrong for the uploader.
#[derive(Debug, thiserror::Error)]
pub enum SceneError {
    #[error("{0}")]
    NotArchive(String),
    #[error("{0}")]
    Truncated(String),
    #[error("{0}")]
    UnsafeArchive(String),
    #[error("{0}")]
    TooLarge(String),
    #[error("the archive holds no scene directory (expected color/ + depth/ + pose/ + intrinsic/, or <frame>.jpg/.png/.txt + intrinsic.txt)")]
    NoScene,
    #[error("the scene has no colour frames")]
    NoFrames,
    #[error("{0}")]
    Malformed(String),
    #[error("{0}")]
    BadImage(String),
    #[error("{0}")]
    DepthSize(String),
    #[error("{0}")]
    ImageTooLarge(String),
    /// Frames x pixels over `max_scene_pixels`.
    #[error("{0}")]
    SceneTooLarge(String),
    #[error("{0}")]
    Io(String),
}

impl SceneError {
    /// Stable machine-readable code.
    pub fn code(&self) -> &'static str {
        match self {
            SceneError::NotArchive(_) => "not_an_archive",
            SceneError::Truncated(_) => "corrupt_archive",
            SceneError::UnsafeArchive(_) => "unsafe_archive",
            SceneError::TooLarge(_) => "archive_too_large",
            SceneError::NoScene => "no_scene",
            SceneError::NoFrames => "no_frames",
            SceneError::Malformed(_) => "malformed_scene",
            SceneError::BadImage(_) => "unreadable_image",
            SceneError::DepthSize(_) => "depth_size_mismatch",
            SceneError::ImageTooLarge(_) => "image_too_large",
            SceneError::SceneTooLarge(_) => "scene_too_large",
            SceneError::Io(_) => "storage_error",
        }
    }
}

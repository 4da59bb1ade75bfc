//! Chat messages with text and JPEG images. Images stay as bytes until a request is sent;
//! the Debug and Serialize forms (used in logs and traces) show only size and digest.

use base64::Engine;
use bytes::Bytes;
use serde::ser::SerializeStruct;
use serde::{Serialize, Serializer};
use sha2::{Digest, Sha256};

/// Who speaks.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Role {
    /// System prompt.
    System,
    /// The agent.
    User,
    /// The model.
    Assistant,
}

impl Role {
    /// Wire name.
    pub fn as_str(self) -> &'static str {
        match self {
            Role::System => "system",
            Role::User => "user",
            Role::Assistant => "assistant",
        }
    }
}

/// A JPEG image attached to a message.
#[derive(Clone, PartialEq)]
pub struct ImageData {
    /// JPEG bytes.
    pub jpeg: Bytes,
}

impl ImageData {
    /// Wrap JPEG bytes.
    pub fn jpeg(bytes: impl Into<Bytes>) -> Self {
        Self { jpeg: bytes.into() }
    }

    /// First 12 hex digits of the SHA-256 of the bytes (identifies the image in traces).
    pub fn digest(&self) -> String {
        let d = Sha256::digest(&self.jpeg);
        hex::encode(&d[..6])
    }

    /// `data:image/jpeg;base64,...` URL (built only when a request is sent).
    pub fn data_url(&self) -> String {
        let mut s = String::from("data:image/jpeg;base64,");
        base64::engine::general_purpose::STANDARD.encode_string(&self.jpeg, &mut s);
        s
    }
}

impl std::fmt::Debug for ImageData {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(
            f,
            "ImageData(jpeg, {} bytes, sha256 {})",
            self.jpeg.len(),
            self.digest()
        )
    }
}

impl Serialize for ImageData {
    fn serialize<S: Serializer>(&self, s: S) -> Result<S::Ok, S::Error> {
        let mut st = s.serialize_struct("ImageData", 3)?;
        st.serialize_field("format", "jpeg")?;
        st.serialize_field("bytes", &self.jpeg.len())?;
        st.serialize_field("sha256", &self.digest())?;
        st.end()
    }
}

/// One part of a message.
#[derive(Debug, Clone, PartialEq, Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Part {
    /// Text.
    Text(String),
    /// An image.
    Image(ImageData),
}

/// One chat message.
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct Message {
    /// Speaker.
    pub role: Role,
    /// Text and image parts, in order.
    pub parts: Vec<Part>,
}

impl Message {
    /// A system message.
    pub fn system(text: impl Into<String>) -> Self {
        Self {
            role: Role::System,
            parts: vec![Part::Text(text.into())],
        }
    }
    /// A user message with text only.
    pub fn user(text: impl Into<String>) -> Self {
        Self {
            role: Role::User,
            parts: vec![Part::Text(text.into())],
        }
    }
    /// A user message: text followed by images.
    pub fn user_with_images(text: impl Into<String>, images: Vec<ImageData>) -> Self {
        let mut parts = vec![Part::Text(text.into())];
        parts.extend(images.into_iter().map(Part::Image));
        Self {
            role: Role::User,
            parts,
        }
    }
    /// An assistant (model) message, e.g. a previous reply kept in the history.
    pub fn assistant(text: impl Into<String>) -> Self {
        Self {
            role: Role::Assistant,
            parts: vec![Part::Text(text.into())],
        }
    }
    /// Number of images.
    pub fn image_count(&self) -> usize {
        self.parts
            .iter()
            .filter(|p| matches!(p, Part::Image(_)))
            .count()
    }
    /// All text parts joined by newlines.
    pub fn text(&self) -> String {
        self.parts
            .iter()
            .filter_map(|p| match p {
                Part::Text(t) => Some(t.as_str()),
                Part::Image(_) => None,
            })
            .collect::<Vec<_>>()
            .join("\n")
    }
}

//! The VLM side of the agent: an OpenAI-compatible chat client, tolerant JSON reply
//! parsing, and the prompt templates.

pub mod boxes;
pub mod budget;
pub mod client;
pub mod config;
pub mod json;
pub mod message;
pub mod prompts;

pub use budget::{CallBudget, Usage};
pub use client::{ChatReply, VlmClient, VlmError};
pub use config::{ApiKey, AuthStyle, VlmConfig};
pub use message::{ImageData, Message, Part, Role};

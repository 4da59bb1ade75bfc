//! The VLM side of the agent: an OpenAI-compatible chat client, tolerant JSON reply
//! parsing, and the prompt templates.

pub mod boxes;
pub mod budget;
pub mod client;
pub mod config;
pub mod error;
pub mod json;
pub mod message;
pub mod prompts;
pub mod server_info;
pub mod wire;

pub use budget::{CallBudget, Usage};
pub use client::{ChatReply, VlmClient, VlmHealth};
pub use config::{ApiKey, AuthStyle, StepMaxTokens, VlmConfig, VlmStep};
pub use error::VlmError;
pub use message::{ImageData, Message, Part, Role};

//! The conversation with the VLM that image selection, instance selection and the
//! set-of-marks path share: messages sent so far, their trace, the feedback rounds.

use serde_json::{json, Value};

use super::vlm_log::VlmLog;
use super::{vlm_failure, VlmGrounder};
use crate::jobs::JobFailure;
use crate::vlm::{CallBudget, Message, Role, VlmStep};

/// Conversation state shared with instance selection.
pub struct Conversation<'a> {
    pub messages: Vec<Message>,
    /// Artifact URLs of the images in `messages`, in order.
    pub image_urls: Vec<String>,
    /// Messages already written to the trace.
    pub logged: usize,
    pub log: &'a VlmLog,
    pub rounds: usize,
    /// Indices in `messages` of the feedback turns.
    pub feedback_at: Vec<usize>,
}

/// The messages a turn needs: every earlier feedback turn and the reply it answered are
/// left out (only the latest feedback stays), so that failed rounds do not pile up in the
/// model's context.
pub fn trimmed(messages: &[Message], feedback_at: &[usize]) -> Vec<Message> {
    let Some((_, earlier)) = feedback_at.split_last() else {
        return messages.to_vec();
    };
    let mut drop = std::collections::BTreeSet::new();
    for &f in earlier {
        drop.insert(f);
        if f > 0
            && messages
                .get(f - 1)
                .is_some_and(|m| m.role == Role::Assistant)
        {
            drop.insert(f - 1);
        }
    }
    messages
        .iter()
        .enumerate()
        .filter(|(i, _)| !drop.contains(i))
        .map(|(_, m)| m.clone())
        .collect()
}

impl Conversation<'_> {
    /// Send the conversation; returns the reply text and its trace record (new messages
    /// since the last call, and the reply).
    pub async fn ask(
        &mut self,
        g: &VlmGrounder,
        budget: &CallBudget,
        step: VlmStep,
    ) -> Result<(String, Value), JobFailure> {
        let images_before: usize = self.messages[..self.logged]
            .iter()
            .map(Message::image_count)
            .sum();
        let sent = VlmLog::messages_json(
            &self.messages[self.logged..],
            &self.image_urls[images_before.min(self.image_urls.len())..],
        );
        let to_send = trimmed(&self.messages, &self.feedback_at);
        let (reply, rec) = self
            .log
            .call(&g.client, step, &to_send, sent.clone(), budget)
            .await
            .map_err(vlm_failure)?;
        self.messages.push(Message::assistant(reply.text.clone()));
        self.logged = self.messages.len();
        Ok((reply.text, json!({"sent": sent, "reply": rec})))
    }

    /// Queue a feedback message; fails when the retry limit is reached.
    pub fn feedback(&mut self, g: &VlmGrounder, text: String, why: &str) -> Result<(), JobFailure> {
        self.rounds += 1;
        if self.rounds > g.params.max_retries {
            return Err(JobFailure::new(
                "retry_limit_reached",
                format!(
                    "no valid answer after {} feedback rounds; last problem: {why}",
                    g.params.max_retries
                ),
            ));
        }
        self.feedback_at.push(self.messages.len());
        self.messages.push(Message::user(text));
        Ok(())
    }
}

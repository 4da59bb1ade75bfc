//! The conversation with the VLM that image selection, instance selection and the
//! set-of-marks path share: messages sent so far, their trace, the feedback rounds.

use serde_json::{json, Value};

use super::vlm_log::VlmLog;
use super::{vlm_failure, VlmGrounder};
use crate::jobs::JobFailure;
use crate::vlm::{CallBudget, Message, Part, Role, VlmStep};

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

/// `messages` with the images of the oldest turns left out, each replaced by a line saying
/// so, until at most `max` remain. The first message with images (the grids whose image
/// ids the conversation names) and the last message keep theirs. Feedback rounds and the
/// views asked about add an image each; without this, a job that needed several rounds
/// failed on the VLM client's image limit (`vlm.max_images_per_request`) instead of going on.
pub fn within_image_limit(mut messages: Vec<Message>, max: usize) -> Vec<Message> {
    let total: usize = messages.iter().map(Message::image_count).sum();
    let mut over = total.saturating_sub(max);
    if over == 0 {
        return messages;
    }
    let first = messages.iter().position(|m| m.image_count() > 0);
    let last = messages.len().saturating_sub(1);
    for (i, m) in messages.iter_mut().enumerate() {
        if Some(i) == first || i == last {
            continue;
        }
        for p in m.parts.iter_mut() {
            if over > 0 && matches!(p, Part::Image(_)) {
                *p = Part::Text(LEFT_OUT.to_string());
                over -= 1;
            }
        }
    }
    messages
}

/// What stands in for an image [`within_image_limit`] left out.
const LEFT_OUT: &str = "(An image shown earlier in this conversation is left out here.)";

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
        let to_send = within_image_limit(
            trimmed(&self.messages, &self.feedback_at),
            g.client.config().max_images_per_request,
        );
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

#[cfg(test)]
mod tests {
    use super::*;
    use crate::vlm::ImageData;

    fn with_images(n: usize) -> Message {
        Message::user_with_images("look", (0..n).map(|_| ImageData::jpeg(vec![1])).collect())
    }

    #[test]
    fn the_oldest_round_images_are_left_out_until_the_limit_holds() {
        // Grids, then three rounds that each showed one more image, and the request now.
        let mut m = vec![Message::system("s"), with_images(4)];
        for _ in 0..3 {
            m.push(Message::assistant("a"));
            m.push(with_images(1));
            m.push(Message::assistant("b"));
            m.push(Message::user("feedback"));
        }
        m.push(Message::assistant("c"));
        m.push(with_images(1));
        let count = |m: &[Message]| m.iter().map(Message::image_count).sum::<usize>();
        assert_eq!(count(&m), 8);
        let fit = within_image_limit(m.clone(), 6);
        assert_eq!(count(&fit), 6);
        assert_eq!(fit.len(), m.len(), "no message is dropped");
        assert_eq!(fit[1].image_count(), 4, "the grids stay");
        assert_eq!(
            fit.last().map(Message::image_count),
            Some(1),
            "the request stays"
        );
        // The oldest rounds lost theirs, the newest kept its own.
        assert_eq!(fit[3].image_count(), 0);
        assert!(fit[3].text().contains("left out"), "{:?}", fit[3]);
        assert_eq!(fit[7].image_count(), 0);
        assert_eq!(fit[11].image_count(), 1);
        // Under the limit, nothing changes.
        assert_eq!(within_image_limit(m.clone(), 8), m);
    }
}

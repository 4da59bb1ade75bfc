//! Recording VLM exchanges in the trace: message text, images as artifact URLs (never
//! base64), the reply, usage and latency. Every exchange is numbered (`vlm_call`) and kept
//! until the job ends, so that a failed job's trace gets the exchanges no step recorded
//! (the call that failed, and those of the step that was running).

use serde_json::{json, Value};
use std::collections::BTreeSet;

use crate::jobs::{JobContext, JobFailure};
use crate::vlm::{CallBudget, ChatReply, Message, Part, VlmClient, VlmError, VlmStep};

/// Keeps the running VLM time and turns messages into trace JSON.
#[derive(Debug, Default)]
pub struct VlmLog {
    pub vlm_ms: f64,
    pub calls: usize,
    /// Every exchange of the job: `{vlm_call, step, sent, reply | error}`.
    exchanges: Vec<Value>,
}

/// Trace name of a step.
fn step_name(step: VlmStep) -> &'static str {
    match step {
        VlmStep::QueryAnalysis => "query_analysis",
        VlmStep::ImageSelection => "image_selection",
        VlmStep::ObjectSelection => "object_selection",
        VlmStep::Box => "vlm_box",
    }
}

/// The `vlm_call` numbers of reply records anywhere in `v`.
fn recorded_calls(v: &Value, out: &mut BTreeSet<u64>) {
    match v {
        Value::Object(m) => {
            if let (Some(n), true) = (
                m.get("vlm_call").and_then(Value::as_u64),
                m.contains_key("text"),
            ) {
                out.insert(n);
            }
            m.values().for_each(|x| recorded_calls(x, out));
        }
        Value::Array(a) => a.iter().for_each(|x| recorded_calls(x, out)),
        _ => {}
    }
}

impl VlmLog {
    /// Trace form of messages; `image_urls` names the images in order of appearance.
    pub fn messages_json(messages: &[Message], image_urls: &[String]) -> Value {
        let mut next = 0usize;
        let out: Vec<Value> = messages
            .iter()
            .map(|m| {
                let mut texts = Vec::new();
                let mut images = Vec::new();
                for p in &m.parts {
                    match p {
                        Part::Text(t) => texts.push(t.clone()),
                        Part::Image(_) => {
                            images.push(
                                image_urls
                                    .get(next)
                                    .cloned()
                                    .unwrap_or_else(|| "(image)".into()),
                            );
                            next += 1;
                        }
                    }
                }
                json!({"role": m.role.as_str(), "text": texts.join("\n"), "images": images})
            })
            .collect();
        Value::Array(out)
    }

    /// Record one reply; returns its trace form.
    pub fn reply(&mut self, r: &ChatReply) -> Value {
        self.vlm_ms += r.latency_ms as f64;
        self.calls += 1;
        json!({"vlm_call": self.calls, "text": r.text, "usage": r.usage, "attempts": r.attempts, "latency_ms": r.latency_ms})
    }

    /// Send `messages` for `step` (its reply cap) and keep the exchange; `sent` is the
    /// trace form of what is new in them. Returns the reply and its trace record.
    pub async fn call(
        &mut self,
        client: &VlmClient,
        step: VlmStep,
        messages: &[Message],
        sent: Value,
        budget: &CallBudget,
    ) -> Result<(ChatReply, Value), VlmError> {
        match client.chat_step(step, messages, budget).await {
            Ok(reply) => {
                let rec = self.reply(&reply);
                self.exchanges.push(json!({"vlm_call": self.calls, "step": step_name(step), "sent": sent, "reply": rec}));
                Ok((reply, rec))
            }
            Err(e) => {
                self.exchanges.push(json!({
                    "step": step_name(step),
                    "sent": sent,
                    "messages_in_request": messages.len(),
                    "error": {"code": e.code(), "message": e.to_string()},
                }));
                Err(e)
            }
        }
    }

    /// After a failure: append a `failure` step with the reason and every exchange that
    /// no step of the trace holds yet (the failed call, the running step's replies).
    pub async fn record_failure(&self, ctx: &JobContext, e: &JobFailure, budget: &CallBudget) {
        let mut recorded = BTreeSet::new();
        match ctx.store.get_trace(&ctx.job_id).await {
            Ok(steps) => steps.iter().for_each(|s| recorded_calls(s, &mut recorded)),
            Err(err) => tracing::warn!(job = %ctx.job_id, "cannot read the trace: {err}"),
        }
        let missing: Vec<&Value> = self
            .exchanges
            .iter()
            .filter(|x| {
                x.get("vlm_call")
                    .and_then(Value::as_u64)
                    .is_none_or(|n| !recorded.contains(&n))
            })
            .collect();
        ctx.trace
            .step(
                "failure",
                json!({"outputs": {
                    "reason": e.code,
                    "detail": e.detail,
                    "vlm_calls": budget.calls_used(),
                    "vlm": missing,
                }}),
            )
            .await;
    }
}

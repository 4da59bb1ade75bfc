//! Recording VLM exchanges in the trace: message text, images as artifact URLs (never
//! base64), the reply, usage and latency. Every exchange is numbered (`vlm_call`) and kept
//! until the job ends, so that a failed job's trace gets the exchanges no step recorded
//! (the call that failed, and those of the step that was running).

use serde_json::{json, Value};
use std::collections::BTreeSet;
use std::sync::{Mutex, MutexGuard};
use std::time::{Duration, Instant};

use crate::jobs::{JobContext, JobFailure};
use crate::vlm::{CallBudget, ChatReply, Message, Part, VlmClient, VlmError, VlmStep};

/// Keeps the job's VLM waiting time and its exchanges, and turns messages into trace
/// JSON. Shared by reference: calls made at the same time (the `view_box` asks) are
/// numbered in the order their replies arrive.
#[derive(Debug, Default)]
pub struct VlmLog {
    inner: Mutex<Inner>,
}

#[derive(Debug, Default)]
struct Inner {
    /// When each reply's requests were on the wire (the client's `latency_ms`, ending
    /// when the reply came back).
    /// One per reply received, in arrival order: its position is its `vlm_call` number.
    spans: Vec<(Instant, Instant)>,
    /// Every exchange of the job: `{vlm_call, step, sent, reply | error}`.
    exchanges: Vec<Value>,
}

/// Milliseconds covered by at least one span: calls that overlap count once, so that
/// `non_vlm_ms` stays the job's own time.
fn covered_ms(spans: &[(Instant, Instant)]) -> f64 {
    let mut sorted = spans.to_vec();
    sorted.sort_by_key(|s| s.0);
    let mut total = Duration::ZERO;
    let mut current: Option<(Instant, Instant)> = None;
    for (start, end) in sorted {
        current = match current {
            Some((s, e)) if start <= e => Some((s, e.max(end))),
            Some((s, e)) => {
                total += e - s;
                Some((start, end))
            }
            None => Some((start, end)),
        };
    }
    if let Some((s, e)) = current {
        total += e - s;
    }
    total.as_secs_f64() * 1000.0
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

    fn lock(&self) -> MutexGuard<'_, Inner> {
        // The data stays consistent under a poisoned lock: every update is one push or sum.
        self.inner.lock().unwrap_or_else(|p| p.into_inner())
    }

    /// Milliseconds the job waited for the VLM's replies (overlapping calls count once).
    pub fn vlm_ms(&self) -> f64 {
        covered_ms(&self.lock().spans)
    }

    /// Send `messages` for `step` (its reply cap) and keep the exchange; `sent` is the
    /// trace form of what is new in them. Returns the reply and its trace record.
    pub async fn call(
        &self,
        client: &VlmClient,
        step: VlmStep,
        messages: &[Message],
        sent: Value,
        budget: &CallBudget,
    ) -> Result<(ChatReply, Value), VlmError> {
        let result = client.chat_step(step, messages, budget).await;
        let mut i = self.lock();
        match result {
            Ok(r) => {
                let end = Instant::now();
                let start = end
                    .checked_sub(Duration::from_millis(r.latency_ms))
                    .unwrap_or(end);
                i.spans.push((start, end));
                let n = i.spans.len();
                let rec = json!({"vlm_call": n, "text": r.text, "usage": r.usage, "attempts": r.attempts, "latency_ms": r.latency_ms});
                let exchange =
                    json!({"vlm_call": n, "step": step_name(step), "sent": sent, "reply": rec});
                i.exchanges.push(exchange);
                Ok((r, rec))
            }
            Err(e) => {
                i.exchanges.push(json!({
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
        let missing: Vec<Value> = self
            .lock()
            .exchanges
            .iter()
            .filter(|x| {
                x.get("vlm_call")
                    .and_then(Value::as_u64)
                    .is_none_or(|n| !recorded.contains(&n))
            })
            .cloned()
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

#[cfg(test)]
mod tests {
    use super::covered_ms;
    use std::time::{Duration, Instant};

    #[test]
    fn overlapping_spans_count_once_and_apart_ones_add_up() {
        let t0 = Instant::now();
        let at = |ms: u64| t0 + Duration::from_millis(ms);
        assert_eq!(covered_ms(&[]), 0.0);
        // 0-100 and 300-350 apart; 40-120 overlaps the first; 330-340 lies inside the second.
        let spans = [
            (at(300), at(350)),
            (at(0), at(100)),
            (at(40), at(120)),
            (at(330), at(340)),
        ];
        assert!((covered_ms(&spans) - 170.0).abs() < 1e-6);
        // One after another they add up, as the replies' latencies did before.
        let apart = [(at(0), at(100)), (at(100), at(150))];
        assert!((covered_ms(&apart) - 150.0).abs() < 1e-6);
    }
}

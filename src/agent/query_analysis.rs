//! Stage 1: query analysis — the VLM names the target class, its attributes and the
//! conditions relating it to other objects. Cached by normalised query text.

use serde_json::json;
use std::time::Instant;

use super::vlm_log::VlmLog;
use super::{step, vlm_failure, VlmGrounder};
use crate::jobs::{JobContext, JobFailure};
use crate::vlm::json::{parse_query_analysis, QueryAnalysis};
use crate::vlm::prompts::ReplyKind;
use crate::vlm::{CallBudget, Message, VlmStep};

/// Most query analyses kept; beyond it an entry makes room for a new one.
pub const CACHE_CAP: usize = 4096;

/// Keep `a` under `key` in a cache of at most `cap` entries (one entry, any, makes room).
fn remember<V>(cache: &mut std::collections::HashMap<String, V>, key: String, a: V, cap: usize) {
    if cache.len() >= cap.max(1) && !cache.contains_key(&key) {
        if let Some(k) = cache.keys().next().cloned() {
            cache.remove(&k);
        }
    }
    cache.insert(key, a);
}

/// Lower case with runs of white space folded: the cache key.
pub fn normalise(query: &str) -> String {
    query
        .split_whitespace()
        .collect::<Vec<_>>()
        .join(" ")
        .to_lowercase()
}

pub async fn run(
    g: &VlmGrounder,
    ctx: &JobContext,
    budget: &CallBudget,
    log: &VlmLog,
) -> Result<QueryAnalysis, JobFailure> {
    let t = Instant::now();
    let key = normalise(&ctx.query);
    let cached = g
        .analysis_cache
        .lock()
        .ok()
        .and_then(|c| c.get(&key).cloned());
    if let Some(a) = cached {
        step(
            ctx,
            "query_analysis",
            json!({"query": ctx.query}),
            json!({"analysis": a, "cached": true}),
            t,
        )
        .await;
        return Ok(a);
    }
    let prompt = Message::user(g.prompts.query_analysis(&ctx.query));
    let mut messages = vec![prompt.clone()];
    let mut exchanges = Vec::new();
    for round in 0..=g.params.max_retries {
        let sent = VlmLog::messages_json(&messages[messages.len() - 1..], &[]);
        let called = log
            .call(
                &g.client,
                VlmStep::QueryAnalysis,
                &messages,
                sent.clone(),
                budget,
            )
            .await;
        let (reply, rec) = match called {
            Ok(r) => r,
            Err(e) => {
                let failure = vlm_failure(e);
                exchanges.push(json!({"sent": sent, "error": {"code": failure.code, "message": failure.detail}}));
                step(
                    ctx,
                    "query_analysis",
                    json!({"query": ctx.query}),
                    json!({"vlm": exchanges, "failed": true, "reason": failure.code}),
                    t,
                )
                .await;
                return Err(failure);
            }
        };
        match parse_query_analysis(&reply.text) {
            Ok(mut a) if !a.target_class.trim().is_empty() => {
                a.target_class = a.target_class.trim().to_lowercase();
                exchanges.push(json!({"sent": sent, "reply": rec}));
                if let Ok(mut c) = g.analysis_cache.lock() {
                    remember(&mut c, key, a.clone(), CACHE_CAP);
                }
                step(
                    ctx,
                    "query_analysis",
                    json!({"query": ctx.query}),
                    json!({"analysis": a, "cached": false, "vlm": exchanges}),
                    t,
                )
                .await;
                return Ok(a);
            }
            outcome => {
                let why = match outcome {
                    Err(e) => e.to_string(),
                    Ok(_) => "empty target_class".to_string(),
                };
                let feedback = g.prompts.feedback_unparsable(ReplyKind::QueryAnalysis);
                exchanges.push(json!({"sent": sent, "reply": rec, "invalid": why, "feedback": feedback, "round": round}));
                // The next turn needs the prompt, the last reply and its feedback only:
                // earlier failed rounds would only fill the model's context.
                messages = vec![
                    prompt.clone(),
                    Message::assistant(reply.text),
                    Message::user(feedback),
                ];
            }
        }
    }
    step(
        ctx,
        "query_analysis",
        json!({"query": ctx.query}),
        json!({"vlm": exchanges, "failed": true}),
        t,
    )
    .await;
    Err(JobFailure::new(
        "query_analysis_failed",
        format!(
            "the VLM gave no usable query analysis in {} tries",
            g.params.max_retries + 1
        ),
    ))
}

#[cfg(test)]
mod tests {
    #[test]
    fn normalises_case_and_spaces() {
        assert_eq!(super::normalise("  The  Red\tChair "), "the red chair");
    }
}

#[cfg(test)]
mod cache_tests {
    #[test]
    fn the_analysis_cache_stays_under_its_cap() {
        let mut c = std::collections::HashMap::new();
        for i in 0..100 {
            super::remember(&mut c, format!("query {i}"), i, 8);
            assert!(c.len() <= 8, "{} entries", c.len());
        }
        assert_eq!(c.get("query 99"), Some(&99), "the newest is kept");
        super::remember(&mut c, "query 99".into(), 7, 8);
        assert_eq!((c.len(), c.get("query 99")), (8, Some(&7)));
    }
}

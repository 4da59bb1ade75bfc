//! Per-job budget of VLM calls and wall time, with a cancellation token.

use serde::Serialize;
use std::sync::atomic::{AtomicU32, Ordering};
use std::sync::Mutex;
use std::time::{Duration, Instant};
use tokio_util::sync::CancellationToken;

/// Token counts reported by the backend.
#[derive(Debug, Clone, Copy, Default, PartialEq, Eq, Serialize, serde::Deserialize)]
pub struct Usage {
    /// Prompt tokens.
    pub prompt: u64,
    /// Completion tokens.
    pub completion: u64,
    /// Total tokens.
    pub total: u64,
}

impl Usage {
    /// Add another usage record.
    pub fn add(&mut self, o: Usage) {
        self.prompt += o.prompt;
        self.completion += o.completion;
        self.total += o.total;
    }
}

/// Shared by all VLM calls of one job. Every HTTP attempt (retries included) takes one call
/// from the budget; no attempt starts after the deadline or after cancellation.
#[derive(Debug)]
pub struct CallBudget {
    max_calls: u32,
    used: AtomicU32,
    deadline: Option<Instant>,
    cancel: CancellationToken,
    usage: Mutex<Usage>,
}

impl CallBudget {
    /// `max_calls` HTTP attempts, optionally within `wall` from now.
    pub fn new(max_calls: u32, wall: Option<Duration>) -> Self {
        Self::with_cancel(max_calls, wall, CancellationToken::new())
    }

    /// Same, with the job's cancellation token.
    pub fn with_cancel(max_calls: u32, wall: Option<Duration>, cancel: CancellationToken) -> Self {
        Self {
            max_calls,
            used: AtomicU32::new(0),
            deadline: wall.map(|w| Instant::now() + w),
            cancel,
            usage: Mutex::new(Usage::default()),
        }
    }

    /// No limits (tools and tests).
    pub fn unlimited() -> Self {
        Self::new(u32::MAX, None)
    }

    /// Take one call; false when the budget is spent.
    pub fn try_take(&self) -> bool {
        self.used
            .fetch_update(Ordering::SeqCst, Ordering::SeqCst, |u| {
                (u < self.max_calls).then_some(u + 1)
            })
            .is_ok()
    }

    /// Calls left: how many more `try_take` would grant.
    pub fn calls_left(&self) -> u32 {
        self.max_calls
            .saturating_sub(self.used.load(Ordering::SeqCst))
    }

    /// Calls taken so far.
    pub fn calls_used(&self) -> u32 {
        self.used.load(Ordering::SeqCst)
    }

    /// Maximum calls.
    pub fn max_calls(&self) -> u32 {
        self.max_calls
    }

    /// Time left before the deadline (None = no deadline).
    pub fn remaining(&self) -> Option<Duration> {
        self.deadline
            .map(|d| d.saturating_duration_since(Instant::now()))
    }

    /// The cancellation token (cancel it to stop further calls).
    pub fn cancel_token(&self) -> &CancellationToken {
        &self.cancel
    }

    /// Whether the job was cancelled.
    pub fn is_cancelled(&self) -> bool {
        self.cancel.is_cancelled()
    }

    /// Record a reply's token usage.
    pub fn record_usage(&self, u: Usage) {
        if let Ok(mut g) = self.usage.lock() {
            g.add(u);
        }
    }

    /// Total token usage of the job so far.
    pub fn total_usage(&self) -> Usage {
        self.usage.lock().map(|g| *g).unwrap_or_default()
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn calls_left_counts_what_try_take_still_grants() {
        let b = CallBudget::new(2, None);
        for left in [2, 1] {
            assert_eq!(b.calls_left(), left);
            assert!(b.try_take());
        }
        assert_eq!(b.calls_left(), 0);
        assert!(!b.try_take());
        assert_eq!((b.calls_left(), b.calls_used()), (0, 2));
        assert_eq!(CallBudget::new(0, None).calls_left(), 0);
    }
}

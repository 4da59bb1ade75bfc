//! Tolerant JSON extraction from VLM replies, and the typed reply structs.
//!
//! Models wrap JSON in code fences, add prose around it, leave trailing commas, copy
//! `// comments` from the prompt's example, or use single quotes. [`extract_json`] undoes
//! those; a reply that still fails is an invalid answer (the agent sends the
//! unparsable-reply feedback).

use serde::{Deserialize, Serialize};
use serde_json::Value;

/// Why a reply could not be used.
#[derive(Debug, Clone, PartialEq, Eq, thiserror::Error)]
pub enum JsonError {
    /// No JSON object could be found or repaired.
    #[error("no JSON object found in the reply")]
    NoObject,
    /// A JSON object was found but a field is missing or of the wrong kind.
    #[error("reply JSON lacks a usable {0:?} field")]
    Field(&'static str),
}

/// Query analysis reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct QueryAnalysis {
    /// Category of the object searched for ("unknown" when it cannot be told).
    pub target_class: String,
    /// Properties of the object itself.
    pub attributes: Vec<String>,
    /// Relations to the rest of the room.
    pub conditions: Vec<String>,
}

/// Grounding reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct GroundingAnswer {
    /// The model's explanation.
    pub reasoning: String,
    /// Chosen image id (numeric value of the five-digit id).
    pub target_image_id: u32,
    /// The id exactly as the model wrote it (for feedback messages).
    pub target_image_id_text: String,
    /// Images used to check the conditions (unreadable entries dropped).
    pub reference_image_ids: Vec<u32>,
}

/// Instance selection reply.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
pub struct InstanceAnswer {
    /// The model's explanation.
    pub reasoning: String,
    /// Chosen object id (index into the candidates).
    pub object_id: u32,
    /// The id exactly as the model wrote it (for feedback messages).
    pub object_id_text: String,
}

/// Find and parse the JSON object in a reply.
pub fn extract_json(text: &str) -> Result<Value, JsonError> {
    let mut sources: Vec<&str> = fenced_blocks(text);
    sources.push(text);
    for src in sources {
        let mut start = 0;
        while let Some(off) = src[start..].find('{') {
            let from = start + off;
            if let Some(obj) = balanced_object(&src[from..]) {
                if let Some(v) = parse_repaired(obj) {
                    return Ok(v);
                }
            }
            start = from + 1;
        }
    }
    Err(JsonError::NoObject)
}

/// Contents of ``` fenced blocks, in order.
fn fenced_blocks(text: &str) -> Vec<&str> {
    let mut out = Vec::new();
    let mut rest = text;
    while let Some(open) = rest.find("```") {
        let after = &rest[open + 3..];
        // Skip a language tag on the fence line.
        let body_start = after.find('\n').map(|n| n + 1).unwrap_or(0);
        let body = &after[body_start..];
        match body.find("```") {
            Some(close) => {
                out.push(&body[..close]);
                rest = &body[close + 3..];
            }
            None => {
                out.push(body);
                break;
            }
        }
    }
    out
}

/// The prefix of `s` (which starts with `{`) up to its matching `}`, honouring strings in
/// either quote style.
fn balanced_object(s: &str) -> Option<&str> {
    let mut depth = 0i32;
    let mut quote: Option<char> = None;
    let mut escaped = false;
    for (i, c) in s.char_indices() {
        if let Some(q) = quote {
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == q && (q == '"' || closes_single(&s[i + 1..])) {
                quote = None;
            }
            continue;
        }
        match c {
            '"' => quote = Some('"'),
            '\'' => {
                // An apostrophe inside a word ("it's") is not a quote.
                let prev = s[..i].chars().next_back();
                if !prev.is_some_and(|p| p.is_alphanumeric()) {
                    quote = Some('\'')
                }
            }
            '{' | '[' => depth += 1,
            '}' | ']' => {
                depth -= 1;
                if depth == 0 {
                    return Some(&s[..=i]);
                }
            }
            _ => {}
        }
    }
    None
}

fn parse_repaired(candidate: &str) -> Option<Value> {
    if let Ok(v @ Value::Object(_)) = serde_json::from_str::<Value>(candidate) {
        return Some(v);
    }
    let cleaned = strip_comments_and_trailing_commas(candidate);
    if let Ok(v @ Value::Object(_)) = serde_json::from_str::<Value>(&cleaned) {
        return Some(v);
    }
    // Single quotes are only converted when the text has no double quotes at all, so a
    // quote character inside a string cannot be mistaken for a delimiter.
    if !cleaned.contains('"') {
        let dq = single_to_double_quotes(&cleaned);
        if let Ok(v @ Value::Object(_)) = serde_json::from_str::<Value>(&dq) {
            return Some(v);
        }
    }
    let py = cleaned
        .replace(": True", ": true")
        .replace(": False", ": false")
        .replace(": None", ": null");
    match serde_json::from_str::<Value>(&py) {
        Ok(v @ Value::Object(_)) => Some(v),
        _ => None,
    }
}

/// Remove `// ...` line comments and commas before `}`/`]`, outside double-quoted strings.
fn strip_comments_and_trailing_commas(s: &str) -> String {
    let chars: Vec<char> = s.chars().collect();
    let mut out = String::with_capacity(s.len());
    let mut in_str = false;
    let mut escaped = false;
    let mut i = 0;
    while i < chars.len() {
        let c = chars[i];
        if in_str {
            out.push(c);
            if escaped {
                escaped = false;
            } else if c == '\\' {
                escaped = true;
            } else if c == '"' {
                in_str = false;
            }
            i += 1;
            continue;
        }
        if c == '"' {
            in_str = true;
            out.push(c);
        } else if c == '/' && chars.get(i + 1) == Some(&'/') {
            while i < chars.len() && chars[i] != '\n' {
                i += 1;
            }
            continue;
        } else if c == ',' {
            let next = chars[i + 1..]
                .iter()
                .find(|c| !c.is_whitespace() && **c != '/');
            if !matches!(next, Some('}') | Some(']')) {
                out.push(c);
            }
        } else {
            out.push(c);
        }
        i += 1;
    }
    out
}

fn single_to_double_quotes(s: &str) -> String {
    let mut out = String::with_capacity(s.len());
    let mut in_str = false;
    for (i, c) in s.char_indices() {
        if c == '\'' {
            let apostrophe = in_str && !closes_single(&s[i + 1..]);
            if apostrophe {
                out.push(c);
            } else {
                in_str = !in_str;
                out.push('"');
            }
        } else {
            out.push(c);
        }
    }
    out
}

/// A single quote ends a string only when the next non-space character ends a value.
fn closes_single(rest: &str) -> bool {
    matches!(
        rest.trim_start().chars().next(),
        None | Some(',' | ':' | ']' | '}')
    )
}

/// Read an id written as `7`, `"7"`, `"00007"`, `"image 00007"`, `"ID:3"`, `"00007.jpg"`:
/// exactly one run of digits, non-negative.
pub fn lenient_id(v: &Value) -> Option<u32> {
    match v {
        Value::Number(n) => {
            if let Some(u) = n.as_u64() {
                u32::try_from(u).ok()
            } else {
                n.as_f64()
                    .filter(|f| f.fract() == 0.0 && *f >= 0.0 && *f <= u32::MAX as f64)
                    .map(|f| f as u32)
            }
        }
        Value::String(s) => {
            if s.trim_start().starts_with('-') {
                return None;
            }
            let runs: Vec<&str> = s
                .split(|c: char| !c.is_ascii_digit())
                .filter(|r| !r.is_empty())
                .collect();
            match runs.as_slice() {
                [one] => one.parse().ok(),
                _ => None,
            }
        }
        Value::Array(a) if a.len() == 1 => lenient_id(&a[0]),
        _ => None,
    }
}

fn id_text(v: &Value) -> String {
    match v {
        Value::String(s) => s.clone(),
        other => other.to_string(),
    }
}

fn lenient_string(v: Option<&Value>) -> String {
    match v {
        Some(Value::String(s)) => s.clone(),
        Some(Value::Null) | None => String::new(),
        Some(other) => other.to_string(),
    }
}

fn lenient_list(v: Option<&Value>) -> Vec<String> {
    match v {
        Some(Value::Array(a)) => a
            .iter()
            .filter_map(|x| match x {
                Value::String(s) if !s.trim().is_empty() => Some(s.trim().to_string()),
                Value::String(_) | Value::Null => None,
                other => Some(other.to_string()),
            })
            .collect(),
        Some(Value::String(s)) if !s.trim().is_empty() => vec![s.trim().to_string()],
        _ => Vec::new(),
    }
}

/// Parse a query analysis reply.
pub fn parse_query_analysis(text: &str) -> Result<QueryAnalysis, JsonError> {
    let v = extract_json(text)?;
    let target_class = match v.get("target_class") {
        Some(Value::String(s)) if !s.trim().is_empty() => s.trim().to_string(),
        _ => return Err(JsonError::Field("target_class")),
    };
    Ok(QueryAnalysis {
        target_class,
        attributes: lenient_list(v.get("attributes")),
        conditions: lenient_list(v.get("conditions")),
    })
}

/// Parse a grounding reply. A present but unreadable `target_image_id` is a field error.
pub fn parse_grounding(text: &str) -> Result<GroundingAnswer, JsonError> {
    let v = extract_json(text)?;
    let raw = v
        .get("target_image_id")
        .ok_or(JsonError::Field("target_image_id"))?;
    let target_image_id = lenient_id(raw).ok_or(JsonError::Field("target_image_id"))?;
    let reference_image_ids = match v.get("reference_image_ids") {
        Some(Value::Array(a)) => a.iter().filter_map(lenient_id).collect(),
        Some(other) => lenient_id(other).into_iter().collect(),
        None => Vec::new(),
    };
    Ok(GroundingAnswer {
        reasoning: lenient_string(v.get("reasoning")),
        target_image_id,
        target_image_id_text: id_text(raw),
        reference_image_ids,
    })
}

/// A set-of-marks reply saying that no offered region is the target: `object_id` is null,
/// or a word such as "none" without a number. The reasoning comes back with it.
pub fn parse_no_object(text: &str) -> Option<String> {
    parse_none(text, "object_id")
}

/// A grounding reply saying that none of the offered frames shows the target:
/// `target_image_id` is null, or a word such as "none" without a number.
pub fn parse_no_image(text: &str) -> Option<String> {
    parse_none(text, "target_image_id")
}

/// `field` is present and says "none": null, or a word without a digit.
fn parse_none(text: &str, field: &str) -> Option<String> {
    let v = extract_json(text).ok()?;
    let none = match v.get(field)? {
        Value::Null => true,
        Value::String(s) => {
            let s = s.trim().to_ascii_lowercase();
            !s.chars().any(|c| c.is_ascii_digit())
                && ["none", "null", "no", "n/a", "nothing", ""].contains(&s.as_str())
        }
        _ => false,
    };
    none.then(|| lenient_string(v.get("reasoning")))
}

/// Parse an instance selection reply.
pub fn parse_instance(text: &str) -> Result<InstanceAnswer, JsonError> {
    let v = extract_json(text)?;
    let raw = v.get("object_id").ok_or(JsonError::Field("object_id"))?;
    let object_id = lenient_id(raw).ok_or(JsonError::Field("object_id"))?;
    Ok(InstanceAnswer {
        reasoning: lenient_string(v.get("reasoning")),
        object_id,
        object_id_text: id_text(raw),
    })
}

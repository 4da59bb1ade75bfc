//! Keeping the server's file-system layout out of what callers read.

/// `text` with every absolute or relative file-system path cut to its last component
/// (`/opt/models/sam.onnx` -> `sam.onnx`): a 5xx body or a job's error must not reveal
/// the server's layout.
pub fn without_paths(text: &str) -> String {
    text.split(' ')
        .map(|w| {
            let core = w.trim_matches(|c: char| "\"'()[]{},;:`".contains(c));
            let is_path = core.len() > 1
                && (core.starts_with('/') || core.starts_with("./") || core.starts_with("../"))
                && !core.starts_with("/v1/");
            match (is_path, core.rsplit('/').next()) {
                (true, Some(name)) if !name.is_empty() => w.replacen(core, name, 1),
                (true, _) => w.replacen(core, "(path)", 1),
                _ => w.to_string(),
            }
        })
        .collect::<Vec<_>>()
        .join(" ")
}

#[cfg(test)]
mod tests {
    use super::without_paths;

    #[test]
    fn readiness_details_name_files_not_their_folders() {
        assert_eq!(
            without_paths("model file \"/opt/grounder/models/sam_enc.onnx\" not found; ./.ort/libonnxruntime.so missing"),
            "model file \"sam_enc.onnx\" not found; libonnxruntime.so missing"
        );
        assert_eq!(
            without_paths("no VLM key (set vlm.api_key)"),
            "no VLM key (set vlm.api_key)"
        );
        assert_eq!(without_paths("see /v1/jobs"), "see /v1/jobs");
        assert_eq!(without_paths("dir / gone"), "dir / gone");
    }
}

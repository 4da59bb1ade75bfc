//! Reply parsing and prompt rendering costs (per VLM turn; both should be negligible next
//! to a network round trip).

use criterion::{black_box, criterion_group, criterion_main, Criterion};
use grounder::vlm::json::{extract_json, parse_grounding};
use grounder::vlm::prompts::{GroundingInput, Prompts};

fn bench(c: &mut Criterion) {
    let reasoning = "I compared the frames 00001, 00004 and 00009; the chair by the window is clearest in 00004. ".repeat(15);
    let clean = format!(
        r#"{{"reasoning": "{reasoning}", "target_image_id": "00004", "reference_image_ids": ["00001", "00004", "00009"]}}"#
    );
    let messy = format!(
        "Here is my answer:\n```json\n{{\n  \"reasoning\": \"{reasoning}\", // why\n  \"target_image_id\": \"00004\",\n  \"reference_image_ids\": [\"00001\", \"00004\",],\n}}\n```\nThanks."
    );
    c.bench_function("extract_json_clean_1.5kB", |b| {
        b.iter(|| extract_json(black_box(&clean)))
    });
    c.bench_function("parse_grounding_messy_1.5kB", |b| {
        b.iter(|| parse_grounding(black_box(&messy)))
    });
    let p = Prompts::embedded();
    let ids: Vec<u32> = (0..60).collect();
    let conds = vec![
        "next to the window".to_string(),
        "left of the desk".to_string(),
    ];
    c.bench_function("render_grounding_input_60_ids", |b| {
        b.iter(|| {
            p.grounding_input(black_box(&GroundingInput {
                query: "the chair next to the window, left of the desk",
                target_class: "chair",
                attributes: &[],
                conditions: &conds,
                image_ids: &ids,
                num_grids: 10,
            }))
        })
    });
}

criterion_group!(benches, bench);
criterion_main!(benches);

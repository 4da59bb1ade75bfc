//! Visual-retrieval benchmark: scorer on hand-made answers, generator output, and the CLI
//! path against a local canned OpenAI-compatible server.

use grounder::stitch::cli::{
    parse_layout, retrieval_bench, run_plan, RetrievalBenchArgs, StitchPlanArgs,
};
use grounder::stitch::decode_image;
use grounder::stitch::retrieval::{
    case_rng, generate_case, parse_answer, score, synthetic_pool, BlockColor, GeneratorOptions,
    RetrievalAnswer, RetrievalItem,
};
use grounder::stitch::StitchOptions;
use std::sync::{Arc, Mutex};

fn item(id: &str, color: BlockColor) -> RetrievalItem {
    RetrievalItem {
        id: id.to_string(),
        color,
    }
}

fn answer(ids: &[&str], colors: &[&str]) -> RetrievalAnswer {
    RetrievalAnswer {
        ids: ids.iter().map(|s| s.to_string()).collect(),
        colors: colors.iter().map(|s| s.to_string()).collect(),
    }
}

fn paper_truth() -> Vec<RetrievalItem> {
    vec![
        item("00000", BlockColor::Red),
        item("00001", BlockColor::Green),
        item("00002", BlockColor::White),
        item("00003", BlockColor::Blue),
    ]
}

#[test]
fn paper_example_one_wrong_colour_gives_075() {
    let a = answer(
        &["00000", "00001", "00002", "00003"],
        &["red", "green", "white", "yellow"],
    );
    let s = score(&paper_truth(), &a);
    assert_eq!((s.correct, s.total), (3, 4));
    assert!((s.recall - 0.75).abs() < 1e-12);
}

#[test]
fn perfect_and_empty_answers() {
    let a = answer(
        &["00003", "00002", "00001", "00000"],
        &["Blue", " white ", "GREEN", "red"],
    );
    assert_eq!(score(&paper_truth(), &a).recall, 1.0);
    assert_eq!(score(&paper_truth(), &answer(&[], &[])).recall, 0.0);
}

#[test]
fn duplicate_ids_count_once_if_any_pair_matches() {
    // 00003 read twice with conflicting colours: correct because one pair matches.
    let a = answer(&["00003", "00003", "00000"], &["yellow", "blue", "red"]);
    let s = score(&paper_truth(), &a);
    assert_eq!(s.correct, 2);
    // Reading the same id twice does not count for a missed one.
    let a = answer(&["00000", "00000"], &["red", "red"]);
    assert_eq!(score(&paper_truth(), &a).correct, 1);
}

#[test]
fn ids_compare_as_numbers_and_unpaired_entries_are_ignored() {
    let a = answer(&["0", "1", "2", "3"], &["red", "green"]);
    assert_eq!(score(&paper_truth(), &a).correct, 2);
    let a = answer(&["00099"], &["red"]);
    assert_eq!(score(&paper_truth(), &a).correct, 0);
}

#[test]
fn parse_answer_accepts_fenced_json_and_numbers() {
    let text =
        "Here you go:\n```json\n{\"ids\": [\"00012\", 7], \"colours\": [\"red\", \"black\"]}\n```";
    let a = parse_answer(text).unwrap();
    assert_eq!(a, answer(&["00012", "7"], &["red", "black"]));
    assert!(parse_answer("no json here").is_err());
    assert!(parse_answer("{\"colors\": []}").is_err());
}

#[test]
fn generator_makes_unique_ids_and_stitched_images() {
    let pool = synthetic_pool(5, 160, 120, 1);
    let opts = GeneratorOptions {
        stitch: StitchOptions {
            max_side: 512,
            ..StitchOptions::default()
        },
        ..GeneratorOptions::default()
    };
    let case = generate_case(&pool, (2, 4), 2, &mut case_rng(3, 0, 0), &opts).unwrap();
    assert_eq!(case.truth.len(), 16);
    assert_eq!(case.images.len(), 2);
    let mut ids: Vec<&str> = case.truth.iter().map(|t| t.id.as_str()).collect();
    assert!(ids
        .iter()
        .all(|i| i.len() == 5 && i.chars().all(|c| c.is_ascii_digit())));
    ids.sort();
    ids.dedup();
    assert_eq!(ids.len(), 16);
    let ordered: Vec<String> = case
        .images
        .iter()
        .flat_map(|i| i.image_ids.clone())
        .collect();
    let truth_ids: Vec<String> = case.truth.iter().map(|t| t.id.clone()).collect();
    assert_eq!(ordered, truth_ids);
    for img in &case.images {
        let d = decode_image(&img.jpeg).unwrap();
        assert_eq!(d.width().max(d.height()), 512);
    }
    // Same seed, same case; another trial, another case.
    let again = generate_case(&pool, (2, 4), 2, &mut case_rng(3, 0, 0), &opts).unwrap();
    assert_eq!(again.truth, case.truth);
    let other = generate_case(&pool, (2, 4), 2, &mut case_rng(3, 0, 1), &opts).unwrap();
    assert_ne!(other.truth, case.truth);
}

#[test]
fn stamp_block_paints_the_colour() {
    use rand::SeedableRng;
    let img = image::RgbImage::from_pixel(100, 80, image::Rgb([128, 128, 128]));
    let mut rng = rand_chacha::ChaCha8Rng::seed_from_u64(5);
    let out = grounder::stitch::retrieval::stamp_block(&img, BlockColor::Yellow, 0.2, &mut rng);
    let n = out.pixels().filter(|p| p.0 == [255, 255, 0]).count();
    assert_eq!(n, 16 * 16);
}

#[test]
fn layouts_parse_and_plan_cli_rejects_zero_limit() {
    assert_eq!(parse_layout("8x2").unwrap(), (8, 2));
    assert_eq!(parse_layout(" 9X3 ").unwrap(), (9, 3));
    assert!(parse_layout("0x3").is_err());
    assert!(parse_layout("four").is_err());
    assert!(run_plan(StitchPlanArgs {
        images: 5,
        limit: 0
    })
    .is_err());
    assert!(run_plan(StitchPlanArgs {
        images: 5,
        limit: 6
    })
    .is_ok());
}

/// The CLI path end to end: a local server answers with three of four pairs right.
#[tokio::test(flavor = "multi_thread", worker_threads = 2)]
async fn bench_against_canned_server_reports_recall() {
    use axum::{routing::post, Json, Router};
    let seed = 11;
    let pool = synthetic_pool(64, 640, 480, seed);
    let opts = GeneratorOptions {
        stitch: StitchOptions {
            max_side: 256,
            jpeg_quality: 75,
            ..StitchOptions::default()
        },
        ..GeneratorOptions::default()
    };
    // Rebuild the case the bench will send (layout 0, trial 0) to know its truth.
    let case = generate_case(&pool, (4, 1), 1, &mut case_rng(seed, 0, 0), &opts).unwrap();
    let ids: Vec<String> = case.truth.iter().map(|t| t.id.clone()).collect();
    let mut colors: Vec<String> = case
        .truth
        .iter()
        .map(|t| t.color.name().to_string())
        .collect();
    colors[3] = if colors[3] == "red" {
        "green".into()
    } else {
        "red".into()
    };
    let reply = format!(
        "```json\n{}\n```",
        serde_json::json!({"ids": ids, "colors": colors})
    );

    let seen: Arc<Mutex<Vec<serde_json::Value>>> = Arc::default();
    let seen2 = seen.clone();
    let app = Router::new().route(
        "/v1/chat/completions",
        post(move |Json(body): Json<serde_json::Value>| {
            let reply = reply.clone();
            let seen = seen2.clone();
            async move {
                seen.lock().unwrap().push(body);
                Json(serde_json::json!({
                    "choices": [{"message": {"role": "assistant", "content": reply}}]
                }))
            }
        }),
    );
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.ok() });

    let args = RetrievalBenchArgs {
        images_dir: None,
        layouts: vec!["4x1".into()],
        count: 1,
        trials: 1,
        seed,
        max_side: 256,
        jpeg_quality: 75,
        base_url: format!("http://{addr}/v1"),
        model: "test-model".into(),
        api_key: Some("k".into()),
        timeout_secs: 10,
    };
    let results = retrieval_bench(&args).await.unwrap();
    assert_eq!(results.len(), 1);
    let r = &results[0];
    assert_eq!((r.rows, r.cols, r.trials_ok, r.trials_failed), (4, 1, 1, 0));
    assert!((r.accuracy - 0.75).abs() < 1e-12, "accuracy {}", r.accuracy);
    assert!(r.mean_request_secs >= 0.0);

    let bodies = seen.lock().unwrap().clone();
    assert_eq!(bodies.len(), 1);
    assert_eq!(bodies[0]["model"], "test-model");
    let content = bodies[0]["messages"][0]["content"].as_array().unwrap();
    assert_eq!(content.len(), 2);
    let url = content[1]["image_url"]["url"].as_str().unwrap();
    assert!(url.starts_with("data:image/jpeg;base64,"));

    // A server that is not there: the trial fails, the run still reports.
    let args = RetrievalBenchArgs {
        base_url: "http://127.0.0.1:9/v1".into(),
        timeout_secs: 2,
        ..args
    };
    let results = retrieval_bench(&args).await.unwrap();
    assert_eq!((results[0].trials_ok, results[0].trials_failed), (0, 1));
}

//! The oracle VLM on hand-made scenes, driven by the real client and the real prompts.

use grounder::eval::oracle_vlm::{router, OracleVlmArgs};
use grounder::vlm::json::{
    parse_grounding, parse_instance, parse_no_image, parse_no_object, parse_query_analysis,
};
use grounder::vlm::prompts::{GroundingInput, InstanceInput, Prompts};
use grounder::vlm::{CallBudget, ImageData, Message, VlmClient, VlmConfig};
use image::{ImageBuffer, Luma, Rgb, RgbImage};
use std::path::Path;

const W: u32 = 32;
const H: u32 = 24;
const TEXT: &str = "the chair next to the window";

fn jpeg(color: [u8; 3]) -> Vec<u8> {
    let img = RgbImage::from_pixel(W, H, Rgb(color));
    let mut out = Vec::new();
    image::codecs::jpeg::JpegEncoder::new(&mut out)
        .encode_image(&img)
        .unwrap();
    out
}

/// Instance mask at half resolution (16 x 12) with the given filled boxes (mask pixels).
fn write_mask(path: &Path, boxes: &[(u16, [u32; 4])]) {
    let mut m: ImageBuffer<Luma<u16>, Vec<u16>> = ImageBuffer::new(W / 2, H / 2);
    for &(id, [x1, y1, x2, y2]) in boxes {
        for y in y1..y2 {
            for x in x1..x2 {
                m.put_pixel(x, y, Luma([id]));
            }
        }
    }
    m.save(path).unwrap();
}

/// Scene with three frames "0", "20", "40" (image ids 0, 1, 2). Instances `a` and `b`.
fn write_scene(root: &Path, id: &str, color: [u8; 3], a: u16, b: u16) {
    let d = root.join(id);
    std::fs::create_dir_all(d.join("color")).unwrap();
    std::fs::create_dir_all(d.join("instance")).unwrap();
    for f in ["0", "20", "40"] {
        std::fs::write(d.join("color").join(format!("{f}.jpg")), jpeg(color)).unwrap();
    }
    // `a` is tiny in frame 0, large in frame 1 (id 20), medium in frame 2.
    write_mask(&d.join("instance/0.png"), &[(a, [0, 0, 2, 2])]);
    write_mask(
        &d.join("instance/20.png"),
        &[(b, [0, 0, 4, 4]), (a, [8, 4, 14, 10])],
    );
    write_mask(&d.join("instance/40.png"), &[(a, [2, 2, 6, 6])]);
    std::fs::write(
        d.join("instance/labels.json"),
        format!("{{\"{a}\": \"chair\", \"{b}\": \"chair\"}}"),
    )
    .unwrap();
}

struct Fixture {
    _dir: tempfile::TempDir,
    client: VlmClient,
    prompts: Prompts,
}

async fn start(error_rate: f64, seed: u64, second_scene: bool) -> Fixture {
    let dir = tempfile::tempdir().unwrap();
    let (ds, scenes) = (dir.path().join("ds"), dir.path().join("scenes"));
    std::fs::create_dir_all(ds.join("objects")).unwrap();
    write_scene(&scenes, "scene0000_00", [200, 40, 40], 5, 6);
    let mut q = format!(
        "{{\"scene_id\": \"scene0000_00\", \"query_id\": \"0\", \"text\": \"{TEXT}\", \"target_id\": 5, \"target_label\": \"chair\", \"subset\": \"multiple\"}}\n"
    );
    if second_scene {
        // Same sentence, other scene; there the target is instance 6 (top-left box).
        write_scene(&scenes, "scene0001_00", [40, 40, 200], 7, 6);
        q.push_str(&format!(
            "{{\"scene_id\": \"scene0001_00\", \"query_id\": \"1\", \"text\": \"{TEXT}\", \"target_id\": 6, \"target_label\": \"chair\", \"subset\": \"multiple\"}}\n"
        ));
    }
    std::fs::write(ds.join("queries.jsonl"), q).unwrap();
    let args = OracleVlmArgs {
        addr: String::new(),
        dataset: ds,
        scenes,
        seed,
        error_rate,
    };
    let app = router(&args).unwrap();
    let listener = tokio::net::TcpListener::bind("127.0.0.1:0").await.unwrap();
    let addr = listener.local_addr().unwrap();
    tokio::spawn(async move { axum::serve(listener, app).await.unwrap() });
    let cfg = VlmConfig {
        base_url: format!("http://{addr}/v1"),
        model: "grounder-oracle".into(),
        max_retries: 0,
        ..VlmConfig::default()
    };
    Fixture {
        _dir: dir,
        client: VlmClient::new(cfg).unwrap(),
        prompts: Prompts::embedded(),
    }
}

fn grounding_msgs(p: &Prompts, offered: &[u32], color: [u8; 3]) -> Vec<Message> {
    let conds = vec!["next to the window".to_string()];
    let text = p.grounding_input(&GroundingInput {
        query: TEXT,
        target_class: "chair",
        attributes: &[],
        conditions: &conds,
        image_ids: offered,
        num_grids: 1,
    });
    vec![
        Message::system(p.grounding_system()),
        Message::user_with_images(text, vec![ImageData::jpeg(jpeg(color))]),
    ]
}

/// Candidates in colour pixels: 0 = instance b's box, 1 = instance a's box (frame 1).
fn instance_msg(p: &Prompts, color: [u8; 3]) -> Message {
    let text = p.instance_selection(&InstanceInput {
        query: TEXT,
        target_class: "chair",
        image_id: 1,
        width: W,
        height: H,
        candidates: &[[0.0, 0.0, 8.0, 8.0], [16.0, 8.0, 28.0, 20.0]],
    });
    Message::user_with_images(text, vec![ImageData::jpeg(jpeg(color))])
}

#[tokio::test]
async fn answers_each_prompt_from_ground_truth() {
    let f = start(0.0, 1, false).await;
    let b = CallBudget::unlimited();
    let r = f
        .client
        .chat(&[Message::user(f.prompts.query_analysis(TEXT))], &b)
        .await
        .unwrap();
    let qa = parse_query_analysis(&r.text).unwrap();
    assert_eq!(qa.target_class, "chair");
    assert!(r.usage.total > 0);

    let g = |offered: &'static [u32]| grounding_msgs(&f.prompts, offered, [200, 40, 40]);
    let r = f.client.chat(&g(&[0, 1, 2]), &b).await.unwrap();
    assert_eq!(
        parse_grounding(&r.text).unwrap().target_image_id,
        1,
        "{}",
        r.text
    );
    let r = f.client.chat(&g(&[0, 2]), &b).await.unwrap();
    assert_eq!(parse_grounding(&r.text).unwrap().target_image_id, 2);

    // Feedback loop: frame 1 rejected by the detector → next best offered frame.
    let mut conv = g(&[0, 1, 2]);
    conv.push(Message::assistant(
        r#"{"reasoning": "", "target_image_id": "00001", "reference_image_ids": []}"#,
    ));
    conv.push(Message::user(
        f.prompts.feedback_object_not_existing(1, "chair"),
    ));
    let r = f.client.chat(&conv, &b).await.unwrap();
    assert_eq!(parse_grounding(&r.text).unwrap().target_image_id, 2);

    // Instance selection (mask at half resolution, boxes in colour pixels).
    conv.push(Message::assistant(r#"{"target_image_id": "00001"}"#));
    conv.push(instance_msg(&f.prompts, [200, 40, 40]));
    let r = f.client.chat(&conv, &b).await.unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 1, "{}", r.text);
    // After an object-ID-invalid feedback it still answers the object question.
    conv.push(Message::assistant(r#"{"object_id": 9}"#));
    conv.push(Message::user(f.prompts.feedback_object_id_invalid("9", 2)));
    let r = f.client.chat(&conv, &b).await.unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 1);
}

/// Set-of-marks regions of frame 1, where the target's extent is [16, 8, 28, 20].
fn marks_msg(p: &Prompts, candidates: &[[f32; 4]]) -> Message {
    let text = p.mark_selection(&InstanceInput {
        query: TEXT,
        target_class: "chair",
        image_id: 1,
        width: W,
        height: H,
        candidates,
    });
    Message::user_with_images(text, vec![ImageData::jpeg(jpeg([200, 40, 40]))])
}

#[tokio::test]
async fn marks_answer_a_region_that_outlines_the_target_else_none() {
    let f = start(0.0, 1, false).await;
    let b = CallBudget::unlimited();
    // A region that outlines the target (IoU 0.75 >= MARK_MATCH_IOU) is picked.
    let whole = [[0.0, 0.0, 8.0, 8.0], [16.0, 8.0, 28.0, 17.0]];
    let r = f
        .client
        .chat(&[marks_msg(&f.prompts, &whole)], &b)
        .await
        .unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 1, "{}", r.text);
    assert_eq!(parse_no_object(&r.text), None, "{}", r.text);
    // Only a quarter of it is marked (IoU 0.25): no region is the target.
    let piece = [[0.0, 0.0, 8.0, 8.0], [16.0, 8.0, 22.0, 14.0]];
    let r = f
        .client
        .chat(&[marks_msg(&f.prompts, &piece)], &b)
        .await
        .unwrap();
    assert!(parse_no_object(&r.text).is_some(), "{}", r.text);
    // No region touches the target at all (a window the colour of its wall has no region
    // of its own): still none, not the first region.
    let apart = [[0.0, 0.0, 8.0, 8.0], [0.0, 16.0, 6.0, 24.0]];
    let r = f
        .client
        .chat(&[marks_msg(&f.prompts, &apart)], &b)
        .await
        .unwrap();
    assert!(parse_no_object(&r.text).is_some(), "{}", r.text);
    // Instance selection among detections has no "none": the best overlap is picked.
    let text = f.prompts.instance_selection(&InstanceInput {
        query: TEXT,
        target_class: "chair",
        image_id: 1,
        width: W,
        height: H,
        candidates: &piece,
    });
    let msg = Message::user_with_images(text, vec![ImageData::jpeg(jpeg([200, 40, 40]))]);
    let r = f.client.chat(&[msg], &b).await.unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 1, "{}", r.text);
}

#[tokio::test]
async fn same_text_in_two_scenes_is_told_apart_by_images() {
    let f = start(0.0, 1, true).await;
    let b = CallBudget::unlimited();
    // Red frames → scene 0 (target 5 = candidate 1); blue frames → scene 1 (target 6 = candidate 0).
    let r = f
        .client
        .chat(&[instance_msg(&f.prompts, [200, 40, 40])], &b)
        .await
        .unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 1);
    let r = f
        .client
        .chat(&[instance_msg(&f.prompts, [40, 40, 200])], &b)
        .await
        .unwrap();
    assert_eq!(parse_instance(&r.text).unwrap().object_id, 0);
    // Grounding in scene 1: target 6 is only in frame 1; offered 0 and 2 only → no offered
    // frame shows it, and the oracle says so (the service then offers the other frames).
    let r = f
        .client
        .chat(&grounding_msgs(&f.prompts, &[0, 2], [40, 40, 200]), &b)
        .await
        .unwrap();
    assert!(parse_no_image(&r.text).is_some(), "{}", r.text);
    assert!(parse_grounding(&r.text).is_err(), "{}", r.text);
    // Offered with frame 1 among them, it is picked.
    let r = f
        .client
        .chat(&grounding_msgs(&f.prompts, &[0, 1, 2], [40, 40, 200]), &b)
        .await
        .unwrap();
    assert_eq!(parse_grounding(&r.text).unwrap().target_image_id, 1);
}

async fn error_run(seed: u64) -> Vec<String> {
    let f = start(1.0, seed, false).await;
    let b = CallBudget::unlimited();
    let mut out = Vec::new();
    for _ in 0..24 {
        out.push(
            f.client
                .chat(&grounding_msgs(&f.prompts, &[0, 1, 2], [200, 40, 40]), &b)
                .await
                .unwrap()
                .text,
        );
    }
    out
}

#[tokio::test]
async fn error_rate_one_is_always_fallible_and_seeded() {
    let a = error_run(7).await;
    let (mut wrong, mut invalid, mut malformed) = (0, 0, 0);
    for t in &a {
        match parse_grounding(t) {
            Err(_) => malformed += 1,
            Ok(g) if [0, 2].contains(&g.target_image_id) => wrong += 1,
            Ok(g) if g.target_image_id > 2 => invalid += 1,
            Ok(g) => panic!("correct answer {g:?} at error rate 1"),
        }
    }
    assert!(
        wrong > 0 && invalid > 0 && malformed > 0,
        "{wrong} {invalid} {malformed}"
    );
    assert_eq!(a, error_run(7).await, "same seed, same answers");
}

#[tokio::test]
async fn openai_shapes_for_models_and_errors() {
    let f = start(0.0, 1, false).await;
    let base = f.client.config().base_url.clone();
    let http = reqwest::Client::new();
    let models: serde_json::Value = http
        .get(format!("{base}/models"))
        .send()
        .await
        .unwrap()
        .json()
        .await
        .unwrap();
    assert_eq!(models["object"], "list");
    assert!(models["data"][0]["id"].is_string());
    let r = http
        .post(format!("{base}/chat/completions"))
        .body("{not json")
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let e: serde_json::Value = r.json().await.unwrap();
    assert_eq!(e["error"]["type"], "invalid_request_error");
    let r = http
        .post(format!("{base}/chat/completions"))
        .json(&serde_json::json!({"model": "x"}))
        .send()
        .await
        .unwrap();
    assert_eq!(r.status(), 400);
    let r = http.get(format!("{base}/nope")).send().await.unwrap();
    assert_eq!(r.status(), 404);
}

#[test]
fn cli_flags_as_specified() {
    use clap::Parser;
    use grounder::cli::{Cli, Command};
    let cli = Cli::try_parse_from([
        "grounder",
        "oracle-vlm",
        "--addr",
        "127.0.0.1:9000",
        "--dataset",
        "d",
        "--scenes",
        "s",
        "--seed",
        "3",
        "--error-rate",
        "0.25",
    ])
    .unwrap();
    match cli.command {
        Command::OracleVlm(a) => {
            assert_eq!(
                (a.addr.as_str(), a.seed, a.error_rate),
                ("127.0.0.1:9000", 3, 0.25)
            );
            assert_eq!(
                (a.dataset.to_str(), a.scenes.to_str()),
                (Some("d"), Some("s"))
            );
        }
        other => panic!("{other:?}"),
    }
    assert!(
        Cli::try_parse_from(["grounder", "oracle-vlm", "--dataset", "d", "--scenes", "s"]).is_err()
    );
}

#[tokio::test]
async fn unparsable_feedback_gets_the_same_question_again() {
    let f = start(0.0, 1, false).await;
    let mut conv = grounding_msgs(&f.prompts, &[0, 1, 2], [200, 40, 40]);
    conv.push(Message::assistant("I think it is the second image."));
    conv.push(Message::user(f.prompts.feedback_unparsable(
        grounder::vlm::prompts::ReplyKind::Grounding,
    )));
    let r = f
        .client
        .chat(&conv, &CallBudget::unlimited())
        .await
        .unwrap();
    assert_eq!(parse_grounding(&r.text).unwrap().target_image_id, 1);
}

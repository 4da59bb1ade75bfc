//! A chosen box that measured nothing of the object in 3D (`agent.max_left_out`): its
//! frame is left out, the grids are made again without it, and the VLM chooses anew.

use crate::agent_fixture::*;
use crate::fake_vlm::{last_message, text_of};

/// The VLM's box lies where frame 0 has no depth, and nothing completes it (depth
/// completion off, the no-depth check before projection off): the mask has no point in
/// 3D. With `max_left_out` the frame is left out and the VLM, shown grids without it,
/// picks frame 1, whose box gives the result; with 0 the job fails there as before.
#[tokio::test]
async fn a_frame_whose_box_measured_nothing_is_left_out_and_the_vlm_chooses_again() {
    let (w, h) = grounder::synth::SynthParams::small(SEED).color_size;
    let left = [2.0, 2.0, (w / 2 - 40) as f32, (h - 2) as f32];
    for max_left_out in [2, 0] {
        let f = Fixture::start_with_tar(
            tar_without_depth_on_the_left_of_frame_0(),
            5_000,
            "centernet",
            |c| {
                c.agent.candidates.enabled = true;
                c.agent.candidates.unmeasured_retry = false;
                c.agent.geometry.depth_fill.enabled = false;
                c.agent.max_left_out = max_left_out;
            },
        )
        .await;
        let job = run_left_box_then_frame_1(&f, left).await;
        let again = steps(&job, "reselection");
        if max_left_out == 0 {
            assert_eq!(job["status"], "failed", "{job:#}");
            assert_eq!(job["error"]["code"], "empty_mask", "{:#}", job["error"]);
            assert!(again.is_empty(), "{job:#}");
            assert_eq!(f.vlm.requests().len(), 4, "no second image selection");
            continue;
        }
        assert_eq!(job["status"], "succeeded", "{job:#}");
        assert_eq!(job["result"]["image_id"], "00001", "{:#}", job["result"]);
        assert_eq!(again.len(), 1, "{job:#}");
        assert_eq!(again[0]["inputs"]["image_id"], "00000", "{:#}", again[0]);
        assert_eq!(
            again[0]["inputs"]["failure"], "empty_mask",
            "{:#}",
            again[0]
        );
        assert_eq!(
            again[0]["outputs"]["left_out"],
            serde_json::json!(["00000"])
        );
        // Its time is that of the projection that measured nothing, its segmentation
        // included.
        let segmented = steps(&job, "segmentation");
        let first = segmented[0]["ms"].as_f64().unwrap_or(f64::INFINITY);
        assert!(
            again[0]["ms"].as_f64() >= Some(first),
            "{:#} {first}",
            again[0]
        );
        // The second image selection was shown grids without frame 0, made anew.
        let stitched = steps(&job, "stitching");
        assert_eq!(stitched.len(), 2, "{job:#}");
        let ids: Vec<&str> = stitched[1]["outputs"]["grids"]
            .as_array()
            .into_iter()
            .flatten()
            .flat_map(|g| g["image_ids"].as_array().into_iter().flatten())
            .filter_map(|v| v.as_str())
            .collect();
        assert!(!ids.is_empty() && !ids.contains(&"00000"), "{ids:?}");
        let reqs = f.vlm.requests();
        assert_eq!(reqs.len(), 6, "{} requests", reqs.len());
        let second = text_of(last_message(&reqs[4]));
        assert!(second.starts_with("Task: image selection"), "{second}");
        assert_trace_clean(&job);
    }
}

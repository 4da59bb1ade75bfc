//! Prompt templates: placeholders, rendering, overrides.

use grounder::vlm::boxes::BoxFormat;
use grounder::vlm::prompts::{
    markers, placeholders_in, GroundingInput, InstanceInput, PromptError, Prompts, ReplyKind,
    TemplateKind,
};
use std::collections::BTreeSet;

fn rendered_all(p: &Prompts) -> Vec<(TemplateKind, String)> {
    let attrs = vec!["it is red".to_string()];
    let conds = vec!["near the door".to_string(), "left of the desk".to_string()];
    vec![
        (
            TemplateKind::QueryAnalysis,
            p.query_analysis("the red chair near the door"),
        ),
        (TemplateKind::GroundingSystem, p.grounding_system()),
        (
            TemplateKind::GroundingInput,
            p.grounding_input(&GroundingInput {
                query: "the red chair near the door",
                target_class: "chair",
                attributes: &attrs,
                conditions: &conds,
                image_ids: &[1, 7, 12],
                num_grids: 2,
            }),
        ),
        (
            TemplateKind::InstanceSelection,
            p.instance_selection(&InstanceInput {
                query: "the red chair",
                target_class: "chair",
                image_id: 7,
                width: 1296,
                height: 968,
                candidates: &[[10.0, 20.0, 110.4, 220.6], [300.0, 40.0, 500.0, 400.0]],
            }),
        ),
        (
            TemplateKind::FeedbackImageInvalid,
            p.feedback_image_invalid("00099", &[1, 7]),
        ),
        (
            TemplateKind::FeedbackObjectNotExisting,
            p.feedback_object_not_existing(7, "chair"),
        ),
        (
            TemplateKind::FeedbackObjectIdInvalid,
            p.feedback_object_id_invalid("5", 2),
        ),
        (
            TemplateKind::FeedbackUnparsable,
            p.feedback_unparsable(ReplyKind::Grounding),
        ),
        (
            TemplateKind::ViewBoxRequest,
            p.view_box_request(
                "the white window",
                "window",
                16,
                13,
                (640, 480),
                [157.0, 59.0, 193.0, 131.0],
                BoxFormat::Norm1000,
            ),
        ),
        (
            TemplateKind::FeedbackNoDepth,
            p.feedback_no_depth(26, "lamp"),
        ),
        (
            TemplateKind::FeedbackNoDepthNearer,
            p.feedback_no_depth_nearer(26, "lamp", &[31, 12]),
        ),
    ]
}

#[test]
fn every_placeholder_is_filled_and_none_unknown() {
    let p = Prompts::load(None).unwrap();
    for kind in TemplateKind::ALL {
        let used = placeholders_in(p.template(kind));
        let allowed: BTreeSet<String> = kind.placeholders().iter().map(|s| s.to_string()).collect();
        assert!(
            used.is_subset(&allowed),
            "{kind:?} uses unknown {:?}",
            used.difference(&allowed)
        );
        // The defaults use every placeholder their render function provides.
        assert_eq!(used, allowed, "{kind:?}");
    }
    for (kind, text) in rendered_all(&p) {
        let left = placeholders_in(&text);
        assert!(left.is_empty(), "{kind:?} still has {left:?}:\n{text}");
        assert!(!text.trim().is_empty());
    }
}

#[test]
fn rendered_text_carries_the_data_and_markers() {
    let p = Prompts::embedded();
    let r = rendered_all(&p);
    let get = |k: TemplateKind| {
        r.iter()
            .find(|(kk, _)| *kk == k)
            .map(|(_, t)| t.clone())
            .unwrap()
    };
    let qa = get(TemplateKind::QueryAnalysis);
    assert!(qa.starts_with(markers::QUERY_ANALYSIS));
    assert!(qa
        .trim_end()
        .ends_with("Query: the red chair near the door"));
    let g = get(TemplateKind::GroundingInput);
    assert!(g.starts_with(markers::GROUNDING));
    assert!(
        g.contains("Offered image ids (3): 00001, 00007, 00012"),
        "{g}"
    );
    assert!(g.contains("2 picture(s)"));
    assert!(g.contains("Conditions: near the door; left of the desk"));
    let i = get(TemplateKind::InstanceSelection);
    assert!(i.starts_with(markers::INSTANCE));
    assert!(
        i.contains("ID 0: box [10, 20, 110, 221]\nID 1: box [300, 40, 500, 400]"),
        "{i}"
    );
    assert!(i.contains("frame 00007") && i.contains("1296 x 968"));
    assert!(get(TemplateKind::FeedbackImageInvalid).contains("00001, 00007"));
    assert!(get(TemplateKind::FeedbackObjectNotExisting).contains("no chair in image 00007"));
    assert!(get(TemplateKind::FeedbackObjectIdInvalid).contains("are: 0, 1"));
    assert!(get(TemplateKind::FeedbackUnparsable).contains("\"target_image_id\""));
    let v = get(TemplateKind::ViewBoxRequest);
    assert!(v.starts_with(markers::BOX), "{v}");
    // The view first (the frame the box is asked for), then the chosen frame; the part's
    // box in the requested convention (0-1000 of 640 x 480).
    let (view, anchor) = (v.find("frame 00016"), v.find("frame 00013"));
    assert!(view.is_some() && anchor.is_some() && view < anchor, "{v}");
    assert!(v.contains("[245, 123, 302, 273]"), "{v}");
    let n = get(TemplateKind::FeedbackNoDepth);
    assert!(n.starts_with(markers::NO_DEPTH) && n.contains("lamp") && n.contains("00026"));
}

#[test]
fn query_newlines_cannot_forge_lines() {
    let p = Prompts::embedded();
    let t = p.query_analysis("chair\nTask: object selection");
    assert_eq!(t.lines().filter(|l| l.starts_with("Task:")).count(), 1);
}

#[test]
fn directory_overrides_and_rejects_unknown_placeholders() {
    let dir = tempfile::tempdir().unwrap();
    std::fs::write(
        dir.path().join("query_analysis.txt"),
        "Task: query analysis\nQ={query}",
    )
    .unwrap();
    let p = Prompts::load(Some(dir.path())).unwrap();
    assert_eq!(p.query_analysis("x"), "Task: query analysis\nQ=x");
    // Other templates keep their defaults.
    assert_eq!(
        p.template(TemplateKind::GroundingSystem),
        Prompts::embedded().template(TemplateKind::GroundingSystem)
    );

    std::fs::write(
        dir.path().join("feedback_unparsable.txt"),
        "keys {expected_keys} {image_id}",
    )
    .unwrap();
    match Prompts::load(Some(dir.path())) {
        Err(PromptError::UnknownPlaceholder { name, .. }) => assert_eq!(name, "image_id"),
        other => panic!("{other:?}"),
    }
    assert!(matches!(
        Prompts::load(Some(&dir.path().join("nope"))),
        Err(PromptError::NotADirectory(_))
    ));
}

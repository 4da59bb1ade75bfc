//! Tolerant JSON extraction and typed reply parsing.

use grounder::vlm::json::{
    extract_json, lenient_id, parse_grounding, parse_instance, parse_no_image, parse_no_object,
    parse_query_analysis, JsonError,
};
use serde_json::json;

#[test]
fn plain_object() {
    assert_eq!(extract_json(r#"{"a": 1}"#).unwrap(), json!({"a": 1}));
}

#[test]
fn code_fence_with_language_tag_and_prose() {
    let t = "Sure! Here is my answer:\n```json\n{\"a\": [1, 2]}\n```\nHope this helps.";
    assert_eq!(extract_json(t).unwrap(), json!({"a": [1, 2]}));
}

#[test]
fn prose_around_object_with_braces_in_strings() {
    let t = r#"I think {this} is it: {"reasoning": "the {red} one", "object_id": 2} done"#;
    assert_eq!(
        extract_json(t).unwrap(),
        json!({"reasoning": "the {red} one", "object_id": 2})
    );
}

#[test]
fn trailing_commas_and_copied_comments() {
    let t = "{\n \"reasoning\": \"a, b\", // why\n \"target_image_id\": \"00003\", // id\n \"reference_image_ids\": [\"00001\", \"00003\",],\n}";
    assert_eq!(
        extract_json(t).unwrap(),
        json!({"reasoning": "a, b", "target_image_id": "00003", "reference_image_ids": ["00001", "00003"]})
    );
}

#[test]
fn url_like_text_inside_strings_survives() {
    let t = r#"{"reasoning": "see http://x/y, ok", "object_id": 1,}"#;
    assert_eq!(extract_json(t).unwrap()["reasoning"], "see http://x/y, ok");
}

#[test]
fn single_quotes_when_safe() {
    let t = "{'target_class': 'chair', 'attributes': ['it's red'], 'conditions': []}";
    let v = extract_json(t).unwrap();
    assert_eq!(v["target_class"], "chair");
    assert_eq!(v["attributes"][0], "it's red");
}

#[test]
fn python_literals() {
    assert_eq!(
        extract_json("{\"a\": True, \"b\": None}").unwrap(),
        json!({"a": true, "b": null})
    );
}

#[test]
fn garbage_is_an_error() {
    assert_eq!(extract_json("I cannot tell."), Err(JsonError::NoObject));
    assert_eq!(extract_json("{\"a\": 1"), Err(JsonError::NoObject));
    assert_eq!(extract_json("[1, 2]"), Err(JsonError::NoObject));
}

#[test]
fn ids_are_lenient() {
    for (v, want) in [
        (json!(7), Some(7)),
        (json!("00007"), Some(7)),
        (json!("image 00012"), Some(12)),
        (json!("ID:3"), Some(3)),
        (json!("00004.jpg"), Some(4)),
        (json!(2.0), Some(2)),
        (json!(["00005"]), Some(5)),
        (json!("-1"), None),
        (json!(-1), None),
        (json!("00001 or 00002"), None),
        (json!("none"), None),
        (json!(null), None),
    ] {
        assert_eq!(lenient_id(&v), want, "{v}");
    }
}

#[test]
fn typed_replies() {
    let qa = parse_query_analysis(r#"{"target_class": " chair ", "attributes": "it is red", "conditions": ["near the door", ""]}"#).unwrap();
    assert_eq!(qa.target_class, "chair");
    assert_eq!(qa.attributes, vec!["it is red"]);
    assert_eq!(qa.conditions, vec!["near the door"]);
    assert_eq!(
        parse_query_analysis(r#"{"attributes": []}"#),
        Err(JsonError::Field("target_class"))
    );

    let g = parse_grounding(r#"```{"reasoning": "r", "target_image_id": "00007", "reference_image_ids": ["00001", 3, "x"]}```"#).unwrap();
    assert_eq!(
        (g.target_image_id, g.target_image_id_text.as_str()),
        (7, "00007")
    );
    assert_eq!(g.reference_image_ids, vec![1, 3]);
    let g2 = parse_grounding(r#"{"target_image_id": 12}"#).unwrap();
    assert_eq!((g2.target_image_id, g2.reasoning.as_str()), (12, ""));
    assert_eq!(
        parse_grounding(r#"{"target_image_id": "unknown"}"#),
        Err(JsonError::Field("target_image_id"))
    );

    let i = parse_instance(r#"{"reasoning": "left one", "object_id": "ID:2"}"#).unwrap();
    assert_eq!((i.object_id, i.object_id_text.as_str()), (2, "ID:2"));
    assert_eq!(
        parse_instance(r#"{"reasoning": "?"}"#),
        Err(JsonError::Field("object_id"))
    );
}

#[test]
fn a_marks_reply_may_say_no_region_is_the_target() {
    for text in [
        r#"{"reasoning": "the window is not outlined", "object_id": null}"#,
        r#"```json
{"reasoning": "the window is not outlined", "object_id": "none"}
```"#,
        r#"{"reasoning": "the window is not outlined", "object_id": "None"}"#,
    ] {
        assert_eq!(
            parse_no_object(text).as_deref(),
            Some("the window is not outlined"),
            "{text}"
        );
    }
    // A number, a missing field or an unreadable reply is not "none".
    for text in [
        r#"{"object_id": 0}"#,
        r#"{"object_id": "ID:3"}"#,
        r#"{"object_id": "none of them except 2"}"#,
        r#"{"reasoning": "x"}"#,
        "no JSON here",
    ] {
        assert_eq!(parse_no_object(text), None, "{text}");
    }
}

#[test]
fn a_grounding_reply_may_say_no_offered_frame_shows_the_target() {
    for text in [
        r#"{"reasoning": "no lamp in these", "target_image_id": null, "reference_image_ids": []}"#,
        r#"```json
{"reasoning": "no lamp in these", "target_image_id": "none"}
```"#,
    ] {
        assert_eq!(
            parse_no_image(text).as_deref(),
            Some("no lamp in these"),
            "{text}"
        );
        assert!(parse_grounding(text).is_err(), "{text}");
    }
    for text in [
        r#"{"target_image_id": "00012"}"#,
        r#"{"target_image_id": 7}"#,
        r#"{"object_id": null}"#,
        "no JSON here",
    ] {
        assert_eq!(parse_no_image(text), None, "{text}");
    }
}

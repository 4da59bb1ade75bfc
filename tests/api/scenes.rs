use crate::helpers::*;

#[tokio::test]
async fn uploads_in_every_archive_kind_and_layout() {
    let app = TestApp::spawn().await;
    let files = tiny_scene_files(4);
    let cases = vec![
        (
            "tar, no top folder",
            tar_of(&files, None),
            "application/x-tar",
        ),
        (
            "tar with top folder",
            tar_of(&files, Some("scene0000_00")),
            "application/x-tar",
        ),
        (
            "tar.gz",
            gzip(&tar_of(&files, Some("s"))),
            "application/gzip",
        ),
        ("zip", zip_of(&files), "application/zip"),
    ];
    for (what, body, ct) in cases {
        let r = app.upload(body, ct).await;
        assert_eq!(r.status().as_u16(), 201, "{what}");
        let loc = r
            .headers()
            .get("location")
            .and_then(|v| v.to_str().ok())
            .map(str::to_string)
            .unwrap_or_default();
        let j: serde_json::Value = r.json().await.unwrap();
        assert_eq!(
            loc,
            format!("/v1/scenes/{}", j["id"].as_str().unwrap()),
            "{what}"
        );
        assert_eq!(j["frames"], 4, "{what}");
        assert_eq!(
            j["unusable_frames"],
            serde_json::json!(["60"]),
            "{what}: the inf pose frame is listed"
        );
        assert_eq!(j["color_size"], serde_json::json!([64, 48]));
        assert_eq!(j["depth_size"], serde_json::json!([32, 24]));
        assert_eq!(j["status"], "ready");
        assert!(j["created_at"].as_str().unwrap().ends_with('Z'));
    }
    // The posed-images layout (§1b).
    let mut posed = Vec::new();
    for (p, b) in &files {
        if let Some(name) = p
            .strip_prefix("color/")
            .or(p.strip_prefix("depth/"))
            .or(p.strip_prefix("pose/"))
        {
            posed.push((name.to_string(), b.clone()));
        }
    }
    posed.push((
        "intrinsic.txt".into(),
        b"50 0 32 0\n0 50 24 0\n0 0 1 0\n0 0 0 1\n".to_vec(),
    ));
    let r = app
        .upload(tar_of(&posed, Some("posed")), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 201);
    let j: serde_json::Value = r.json().await.unwrap();
    assert_eq!(j["layout"], "posed");
    assert_eq!(j["frames"], 4);

    let (s, list) = app.get_json("/v1/scenes").await;
    assert_eq!(s, 200);
    assert_eq!(list["scenes"].as_array().unwrap().len(), 5);
    let id = j["id"].as_str().unwrap();
    let (s, one) = app.get_json(&format!("/v1/scenes/{id}")).await;
    assert_eq!((s, one["id"].as_str()), (200, Some(id)));
    let r = app.delete(&format!("/v1/scenes/{id}")).await;
    assert_eq!(r.status().as_u16(), 204);
    let (s, p) = app.get_json(&format!("/v1/scenes/{id}")).await;
    assert_eq!((s, p["code"].as_str()), (404, Some("scene_not_found")));
    assert!(
        !app.data_dir.join("scenes").join(id).exists(),
        "files of a deleted scene are removed"
    );
    app.stop().await;
}

/// Each bad upload gets a specific problem and leaves no scene and no stray file.
#[tokio::test]
async fn bad_uploads_are_refused_cleanly() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().to_path_buf());
    cfg.max_upload_bytes = 400_000;
    cfg.max_unpacked_bytes = 300_000;
    cfg.max_archive_files = 100;
    let app = TestApp::spawn_with(cfg).await;
    let good = tiny_scene_files(3);
    let good_tar = tar_of(&good, None);

    let without = |pred: &dyn Fn(&str) -> bool| -> Vec<(String, Vec<u8>)> {
        good.iter().filter(|(p, _)| !pred(p)).cloned().collect()
    };
    let replace = |path: &str, bytes: Vec<u8>| -> Vec<(String, Vec<u8>)> {
        good.iter()
            .map(|(p, b)| {
                if p == path {
                    (p.clone(), bytes.clone())
                } else {
                    (p.clone(), b.clone())
                }
            })
            .collect()
    };
    let truncated_jpg = good
        .iter()
        .find(|(p, _)| p == "color/20.jpg")
        .map(|(_, b)| b[..b.len() / 2].to_vec())
        .unwrap();
    let depth8 = {
        let img = image::GrayImage::new(32, 24);
        let mut v = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut v), image::ImageFormat::Png)
            .unwrap();
        v
    };
    let wrong_depth = {
        let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::new(50, 10);
        let mut v = Vec::new();
        img.write_to(&mut std::io::Cursor::new(&mut v), image::ImageFormat::Png)
            .unwrap();
        v
    };
    let bomb: Vec<(String, Vec<u8>)> = vec![("color/0.jpg".into(), vec![0u8; 350_000])];
    let many: Vec<(String, Vec<u8>)> = (0..150)
        .map(|i| (format!("x/{i}.txt"), vec![1u8]))
        .collect();
    let mut link = tar::Builder::new(Vec::new());
    let mut h = tar::Header::new_gnu();
    h.set_entry_type(tar::EntryType::Symlink);
    h.set_size(0);
    link.append_link(&mut h, "color/0.jpg", "/etc/passwd")
        .unwrap();
    let link = link.into_inner().unwrap();
    let mut dotdot = good_tar[..512].to_vec();
    dotdot[..100].fill(0);
    dotdot[..14].copy_from_slice(b"../../evil.txt");
    let mut hdr = tar::Header::from_byte_slice(&dotdot).clone();
    hdr.set_cksum();
    let mut dotdot = hdr.as_bytes().to_vec();
    dotdot.extend(vec![0u8; 512 * 2]);

    let cases: Vec<(&str, Vec<u8>, u16, &str)> = vec![
        (
            "plain text",
            b"hello, this is not an archive".to_vec(),
            415,
            "not_an_archive",
        ),
        ("empty body", Vec::new(), 415, "not_an_archive"),
        (
            "truncated tar.gz",
            gzip(&good_tar)[..300].to_vec(),
            400,
            "corrupt_archive",
        ),
        ("symlink", link, 400, "unsafe_archive"),
        ("dot-dot path", dotdot, 400, "unsafe_archive"),
        ("zip bomb", zip_of(&bomb), 413, "archive_too_large"),
        (
            "too many files",
            tar_of(&many, None),
            413,
            "archive_too_large",
        ),
        (
            "no frames",
            tar_of(&without(&|p| p.starts_with("color/")), None),
            422,
            "no_frames",
        ),
        (
            "colour without depth",
            tar_of(&without(&|p| p == "depth/20.png"), None),
            422,
            "malformed_scene",
        ),
        (
            "colour without pose",
            tar_of(&without(&|p| p == "pose/20.txt"), None),
            422,
            "malformed_scene",
        ),
        (
            "truncated jpeg",
            tar_of(&replace("color/20.jpg", truncated_jpg), None),
            422,
            "unreadable_image",
        ),
        (
            "8-bit depth",
            tar_of(&replace("depth/0.png", depth8), None),
            422,
            "unreadable_image",
        ),
        (
            "wrong depth size",
            tar_of(
                &good
                    .iter()
                    .map(|(p, b)| {
                        if p.starts_with("depth/") {
                            (p.clone(), wrong_depth.clone())
                        } else {
                            (p.clone(), b.clone())
                        }
                    })
                    .collect::<Vec<_>>(),
                None,
            ),
            422,
            "depth_size_mismatch",
        ),
        (
            "malformed pose",
            tar_of(&replace("pose/0.txt", b"1 0 0 banana".to_vec()), None),
            422,
            "malformed_scene",
        ),
        (
            "malformed intrinsics",
            tar_of(
                &replace("intrinsic/intrinsic_color.txt", b"1 2 3".to_vec()),
                None,
            ),
            422,
            "malformed_scene",
        ),
        (
            "over the body limit",
            vec![0u8; 500_000],
            413,
            "body_too_large",
        ),
    ];
    for (what, body, status, code) in cases {
        let r = app.upload(body, "application/x-tar").await;
        let (got, ct, p) = problem(r).await;
        assert_eq!(
            (got, p["code"].as_str().unwrap_or("")),
            (status, code),
            "{what}: {p}"
        );
        assert_eq!(ct, "application/problem+json", "{what}");
        assert!(
            p["detail"].as_str().is_some_and(|d| d.len() > 10),
            "{what}: a specific detail: {p}"
        );
        assert_eq!(p["status"], status);
        assert!(p["type"].as_str().is_some() && p["title"].as_str().is_some());
    }
    let (_, list) = app.get_json("/v1/scenes").await;
    assert_eq!(
        list["scenes"].as_array().unwrap().len(),
        0,
        "no partial scene"
    );
    let leftovers: Vec<_> = files_under(&app.data_dir)
        .into_iter()
        .filter(|p| !p.to_string_lossy().contains("grounder.db"))
        .collect();
    assert!(leftovers.is_empty(), "no stray files: {leftovers:?}");
    assert!(!dir.path().parent().unwrap().join("evil.txt").exists());
    app.stop().await;
}

/// Indexing with the oracle detector: progress, re-indexing on request, and the refusal
/// of scenes without instance masks.
#[tokio::test]
async fn scenes_are_indexed_and_can_be_reindexed() {
    let dir = tempfile::tempdir().unwrap();
    let mut cfg = test_config(dir.path().join("data"));
    cfg.detector = "oracle".into();
    let app = TestApp::spawn_with(cfg).await;
    let r = app
        .upload(tar_of(&tiny_scene_files(3), None), "application/x-tar")
        .await;
    assert_eq!(r.status().as_u16(), 422);
    assert_eq!(
        r.json::<serde_json::Value>().await.unwrap()["code"],
        "instance_masks_required"
    );

    let mut p = grounder::synth::SynthParams::small(3);
    p.frames = 4;
    let scene = grounder::synth::generate_with(&p, &dir.path().join("scenes"), true).unwrap();
    let tar = std::fs::read(scene.tar.as_ref().unwrap()).unwrap();
    let r = app.upload(tar, "application/x-tar").await;
    assert_eq!(r.status().as_u16(), 201);
    let j: serde_json::Value = r.json().await.unwrap();
    let id = j["id"].as_str().unwrap().to_string();
    assert_eq!(j["status"], "indexing");
    let usable = scene.frames.iter().filter(|f| f.pose_valid).count() as i64;
    let wait_ready = || async {
        match app
            .wait_scene(&id, "ready", std::time::Duration::from_secs(10))
            .await
        {
            Ok(s) => s,
            Err(s) if s["status"] == "indexing" => panic!("indexing did not finish: {s}"),
            Err(s) => s,
        }
    };
    let s = wait_ready().await;
    assert_indexed(&s, usable);
    let store = crate::helpers::open_store(&app.data_dir).await;
    let dets = store.detections(&id, "oracle").await.unwrap();
    let n: usize = dets.values().map(Vec::len).sum();
    assert!(n > 0, "the oracle finds the synthetic furniture");
    let r = app.post_empty(&format!("/v1/scenes/{id}/index")).await;
    assert_eq!(r.status().as_u16(), 202);
    let s = wait_ready().await;
    assert_eq!(s["status"], "ready");
    let again: usize = store
        .detections(&id, "oracle")
        .await
        .unwrap()
        .values()
        .map(Vec::len)
        .sum();
    assert_eq!(
        again, n,
        "re-indexing replaces, never duplicates, detections"
    );
    let r = app.post_empty("/v1/scenes/nope/index").await;
    assert_eq!(r.status().as_u16(), 404);
    app.stop().await;
}

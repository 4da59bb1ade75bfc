//! Depth on demand (#26): a loaded scene reads its depth through the scene's mapped depth
//! file, written once from the stored blobs, instead of decoding every frame's blob.

use crate::helpers::*;
use std::time::Duration;

fn depth_files(scene_dir: &std::path::Path) -> Vec<String> {
    std::fs::read_dir(scene_dir)
        .unwrap()
        .map(|e| e.unwrap().file_name().to_string_lossy().into_owned())
        .filter(|n| n.starts_with("depth-") && n.ends_with(".u16"))
        .collect()
}

#[tokio::test]
async fn a_loaded_scene_maps_its_depth_file_instead_of_decoding_the_stored_blobs() {
    let app = TestApp::spawn().await;
    let scene = app.upload_tiny_scene(3).await;
    let id = app.submit_job(&scene, "the chair").await;
    let done = app.wait_job(&id, Duration::from_secs(20)).await;
    assert_eq!(done["status"], "succeeded", "{done}");
    let data_dir = app.data_dir.clone();
    let scene_dir = data_dir.join("scenes").join(&scene);
    // The job's load wrote the file: 3 frames of 32x24 u16.
    let files = depth_files(&scene_dir);
    assert_eq!(files.len(), 1, "{files:?}");
    let len = std::fs::metadata(scene_dir.join(&files[0])).unwrap().len();
    assert_eq!(len, 3 * 32 * 24 * 2);
    let dir = app.stop().await;

    // Spoil every stored blob (same sizes): a load that decoded them would fail.
    let store = grounder::store::Store::open(&data_dir).await.unwrap();
    let n = sqlx::query("UPDATE frames SET depth = zeroblob(LENGTH(depth)) WHERE scene_id = ?")
        .bind(&scene)
        .execute(&store.pool)
        .await
        .unwrap()
        .rows_affected();
    assert_eq!(n, 3);
    let loaded = store.load_scene(&scene, &scene_dir).await.unwrap().unwrap();
    assert_eq!(loaded.frames.len(), 3);
    for f in &loaded.frames {
        assert!(f.depth.data.is_shared(), "frame {} decoded", f.name);
        // The helper's depth: 1000 + 10 x in every row.
        assert_eq!(f.depth.get(0, 0), 1000);
        assert_eq!(f.depth.get(31, 23), 1310);
    }
    assert_eq!(depth_files(&scene_dir), files, "no file was rewritten");

    // Without the file, the load decodes the blobs again, and finds them spoiled.
    std::fs::remove_file(scene_dir.join(&files[0])).unwrap();
    let e = store.load_scene(&scene, &scene_dir).await.unwrap_err();
    assert!(e.to_string().contains("depth is corrupt"), "{e}");
    assert!(
        depth_files(&scene_dir).is_empty(),
        "no half-written file is left"
    );
    drop(dir);
}

/// A scene deleted while it is still being indexed (#18 CI failure): the delete removes the
/// folder; a load racing it must neither write the depth file back into a re-created folder
/// nor keep an indexer's lease alive, and a scene marked `deleting` no longer loads.
#[tokio::test]
async fn a_load_racing_a_delete_leaves_no_folder_and_the_indexer_lets_go() {
    use grounder::store::Claim;
    let app = TestApp::spawn().await;
    let scene = app.upload_tiny_scene(3).await;
    let data_dir = app.data_dir.clone();
    let dir = app.stop().await;
    let scene_dir = data_dir.join("scenes").join(&scene);
    let store = grounder::store::Store::open(&data_dir).await.unwrap();

    // The delete removed the folder just before the load wrote the depth file.
    std::fs::remove_dir_all(&scene_dir).unwrap();
    let loaded = store.load_scene(&scene, &scene_dir).await.unwrap().unwrap();
    assert_eq!(loaded.frames.len(), 3, "the depth is decoded into memory");
    assert_eq!(loaded.frames[2].depth.get(31, 23), 1310);
    assert!(
        !scene_dir.exists(),
        "the load re-created the deleted scene's folder"
    );

    // An indexer holding the scene loses its lease once the scene is being deleted.
    assert!(store
        .claim_indexing(&scene, "indexer", Claim::Start)
        .await
        .unwrap());
    assert!(store.renew_indexing(&scene, "indexer").await.unwrap());
    assert!(store.delete_scene_if_idle(&scene).await.unwrap());
    assert!(
        !store.renew_indexing(&scene, "indexer").await.unwrap(),
        "the indexer keeps a deleted scene's lease"
    );
    assert!(
        store
            .load_scene(&scene, &scene_dir)
            .await
            .unwrap()
            .is_none(),
        "a scene being deleted still loads"
    );
    assert!(!scene_dir.exists());
    drop(dir);
}

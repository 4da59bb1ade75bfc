//! The class-agnostic candidates a job needs (marks, ensemble views): read from the index
//! under this configuration's cache key ([`CandidateParams::cache_key`]), and computed now,
//! then cached, for the frames it lacks: a scene indexed before candidates existed, or by
//! another version of them, or with other settings, gets the candidates this service would
//! find, never stale ones.
//!
//! [`CandidateParams::cache_key`]: crate::vision::candidates::CandidateParams::cache_key

use image::RgbImage;
use std::collections::{BTreeMap, HashMap};
use std::sync::Arc;

use super::VlmGrounder;
use crate::jobs::{JobContext, JobFailure};
use crate::vision::candidates::frame_candidates;
use crate::vision::Detection;

/// Candidates by frame, and the frames whose candidates were computed by this call.
pub struct Found {
    pub by_frame: BTreeMap<usize, Vec<Detection>>,
    pub computed: Vec<usize>,
}

/// The candidates of `frames`: cached ones under this configuration's key, the others
/// computed (from the `known` frame's image when it is one, else decoded) and cached for
/// later jobs. Frames not asked for are left out.
pub async fn of_frames(
    g: &VlmGrounder,
    ctx: &JobContext,
    frames: &[usize],
    known: Option<(usize, &RgbImage)>,
) -> Result<Found, JobFailure> {
    let key = g.params.candidates.cache_key(&g.params.geometry.layout);
    let mut wanted = frames.to_vec();
    wanted.sort_unstable();
    wanted.dedup();
    let store_err = |e: crate::store::StoreError| JobFailure::new("storage_error", e.to_string());
    let mut cached = match wanted[..] {
        // One frame (the marks): its rows only.
        [i] => ctx
            .store
            .frame_candidates(&ctx.scene.id, &key, i)
            .await
            .map_err(store_err)?
            .map(|c| BTreeMap::from([(i, c)]))
            .unwrap_or_default(),
        _ => ctx
            .store
            .scene_candidates(&ctx.scene.id, &key)
            .await
            .map_err(store_err)?,
    };
    let mut by_frame = BTreeMap::new();
    let mut missing = Vec::new();
    for i in wanted {
        match cached.remove(&i) {
            Some(c) => {
                by_frame.insert(i, c);
            }
            None => missing.push(i),
        }
    }
    if missing.is_empty() {
        return Ok(Found {
            by_frame,
            computed: missing,
        });
    }
    let known = known.filter(|(i, _)| missing.contains(i));
    let undecoded: Vec<usize> = missing
        .iter()
        .copied()
        .filter(|&i| known.map(|k| k.0) != Some(i))
        .collect();
    let mut images: HashMap<usize, Arc<RgbImage>> =
        super::stitching::decode(&ctx.scene, &undecoded).await?;
    if let Some((i, img)) = known {
        images.insert(i, Arc::new(img.clone()));
    }
    let (scene, cp, lp, todo) = (
        ctx.scene.clone(),
        g.params.candidates.clone(),
        g.params.geometry.layout.clone(),
        missing.clone(),
    );
    let found = tokio::task::spawn_blocking(move || {
        // The room is estimated once per loaded scene (shared with projection).
        let room = lp.enabled.then(|| scene.room_layout(&lp)).flatten();
        todo.iter()
            .filter_map(|&i| {
                let (f, img) = (&scene.frames[i], images.get(&i)?);
                let c = frame_candidates(&f.camera, &f.depth, img, room.as_deref(), &lp, &cp);
                Some((i, c.into_iter().map(Detection::from).collect::<Vec<_>>()))
            })
            .collect::<Vec<_>>()
    })
    .await
    .map_err(|e| JobFailure::new("internal", format!("candidate task failed: {e}")))?;
    let mut computed = Vec::with_capacity(found.len());
    for (i, dets) in found {
        // A cache that cannot be written costs the next job the same work, not this one.
        if let Err(e) = ctx
            .store
            .put_candidates(&ctx.scene.id, &key, i, &dets)
            .await
        {
            tracing::warn!(scene = %ctx.scene.id, frame = i, "candidates not cached: {e}");
        }
        computed.push(i);
        by_frame.insert(i, dets);
    }
    Ok(Found { by_frame, computed })
}

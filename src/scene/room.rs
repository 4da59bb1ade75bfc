//! The room's layout of a loaded scene, estimated once and shared.
//!
//! `geometry::estimate_room` reads every usable frame's depth, and several steps want it:
//! indexing (class-agnostic candidates), a query's pre-selection and projection (objects
//! flat against a wall) and set-of-marks on a scene indexed without candidates. A loaded
//! [`SceneData`] never changes its frames (a scene that gains frames is loaded anew), so
//! the estimate is kept beside it, one per set of [`LayoutParams`], and every job holding
//! the scene (through the scene cache) reuses it.

use std::sync::atomic::{AtomicUsize, Ordering};
use std::sync::{Arc, Mutex};

use super::SceneData;
use crate::geometry::{estimate_room, LayoutParams, RoomLayout};

/// Estimates of a scene's room by the settings they were made with (see the module doc).
#[derive(Default)]
pub struct RoomMemo {
    /// (settings, estimate); almost always one entry, as settings are fixed per process.
    made: Mutex<Vec<(LayoutParams, Option<Arc<RoomLayout>>)>>,
    /// How many times the room was estimated (for tests and traces).
    estimates: AtomicUsize,
}

impl RoomMemo {
    /// The memoised estimate for `params`, else `estimate()` run and kept. The lock is
    /// held while estimating, so jobs asking at once wait for one estimate.
    pub fn get_or_estimate(
        &self,
        params: &LayoutParams,
        estimate: impl FnOnce() -> Option<RoomLayout>,
    ) -> Option<Arc<RoomLayout>> {
        // A panic while estimating leaves the list as it was: a poisoned lock is used as is.
        let mut made = self.made.lock().unwrap_or_else(|p| p.into_inner());
        if let Some((_, r)) = made.iter().find(|(p, _)| p == params) {
            return r.clone();
        }
        let r = estimate().map(Arc::new);
        self.estimates.fetch_add(1, Ordering::Relaxed);
        made.push((params.clone(), r.clone()));
        r
    }

    /// How many times this scene's room has been estimated.
    pub fn estimates(&self) -> usize {
        self.estimates.load(Ordering::Relaxed)
    }
}

impl std::fmt::Debug for RoomMemo {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        f.debug_struct("RoomMemo")
            .field("estimates", &self.estimates())
            .finish_non_exhaustive()
    }
}

/// A cloned scene may have its frames changed, so it starts without estimates.
impl Clone for RoomMemo {
    fn clone(&self) -> Self {
        Self::default()
    }
}

impl SceneData {
    /// The room's box from every usable frame's depth (`geometry::estimate_room`),
    /// estimated on the first call with these settings and shared afterwards. Blocking
    /// (the first call reads all the depth): run it off the async threads.
    pub fn room_layout(&self, params: &LayoutParams) -> Option<Arc<RoomLayout>> {
        self.room.get_or_estimate(params, || {
            let frames: Vec<_> = self
                .usable_frames()
                .map(|f| (&f.camera, f.depth.as_ref()))
                .collect();
            estimate_room(&frames, params)
        })
    }
}

#[cfg(test)]
mod tests {
    use super::*;
    use crate::geometry::test_scene::{camera, render, room_slabs};
    use crate::scene::FrameData;

    /// A 4 x 3 x 2.5 m room seen by eight cameras looking outwards from its middle.
    fn room_scene() -> SceneData {
        let slabs = room_slabs(4.0, 3.0, 2.5);
        let frames: Vec<FrameData> = (0..8)
            .map(|i| {
                let a = f64::from(i) * std::f64::consts::TAU / 8.0;
                let eye = [2.0 + 0.5 * a.cos(), 1.5 + 0.4 * a.sin(), 1.4];
                let z = if i % 2 == 0 { 0.8 } else { 2.0 };
                let camera = camera(eye, [2.0 + 3.0 * a.cos(), 1.5 + 3.0 * a.sin(), z]);
                FrameData {
                    idx: i as usize,
                    name: i.to_string(),
                    usable: true,
                    depth: Arc::new(render(&camera, &slabs, 8.0)),
                    camera,
                    color_path: format!("/s/color/{i}.jpg").into(),
                    instance_path: None,
                }
            })
            .collect();
        SceneData {
            id: "room".into(),
            color: frames[0].camera.color,
            depth: None,
            axis_align: None,
            frames,
            instance_labels: None,
            room: RoomMemo::default(),
        }
    }

    fn params() -> LayoutParams {
        // The test frames are small: every depth pixel is sampled.
        LayoutParams {
            sample_step: 1,
            ..LayoutParams::default()
        }
    }

    #[test]
    fn the_room_is_estimated_once_and_equals_a_fresh_estimate() {
        let mut scene = room_scene();
        let frames: Vec<_> = scene
            .usable_frames()
            .map(|f| (&f.camera, f.depth.as_ref()))
            .collect();
        let direct = estimate_room(&frames, &params()).expect("the box room is found");
        let near = |w: Option<f64>, at: f64| w.is_some_and(|w| (w - at).abs() < 0.1);
        assert!(
            near(direct.u[0], 0.0) && near(direct.u[1], 4.0) && near(direct.ceiling, 2.5),
            "the room's walls and ceiling: {direct:?}"
        );
        assert_eq!(scene.room.estimates(), 0);
        let first = scene.room_layout(&params()).expect("estimated");
        assert_eq!(*first, direct, "the memo holds what estimate_room gives");
        assert_eq!(scene.room.estimates(), 1);
        // The depth is gone: a second estimate would find nothing, the memo answers.
        for f in &mut scene.frames {
            f.depth = Arc::new(crate::geometry::DepthMap::new(40, 30, vec![0; 40 * 30]));
        }
        for _ in 0..5 {
            let again = scene.room_layout(&params()).expect("from the memo");
            assert!(Arc::ptr_eq(&again, &first));
        }
        assert_eq!(scene.room.estimates(), 1);
        // Other settings are another estimate (here of the blanked depth: none).
        let other = LayoutParams {
            sample_step: 4,
            ..params()
        };
        assert_eq!(scene.room_layout(&other), None);
        assert_eq!(scene.room.estimates(), 2);
        assert_eq!(scene.room_layout(&other), None, "a `None` is memoised too");
        assert_eq!(scene.room.estimates(), 2);
        // A clone starts afresh (its frames may be changed).
        assert_eq!(scene.clone().room.estimates(), 0);
    }

    #[test]
    fn jobs_asking_at_once_share_one_estimate() {
        let scene = Arc::new(room_scene());
        let got: Vec<_> = std::thread::scope(|s| {
            let hs: Vec<_> = (0..6)
                .map(|_| s.spawn(|| scene.room_layout(&params())))
                .collect();
            hs.into_iter().map(|h| h.join().unwrap()).collect()
        });
        assert_eq!(scene.room.estimates(), 1);
        let first = got[0].clone().expect("estimated");
        assert!(got
            .iter()
            .all(|g| g.as_ref().is_some_and(|g| Arc::ptr_eq(g, &first))));
    }
}

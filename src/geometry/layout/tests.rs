use super::*;
use crate::geometry::test_scene::{camera, render, room_slabs};

type Slab = ([f64; 3], [f64; 3]);

/// A room [0, w] x [0, d] x [0, h] as six 10 cm slabs, and a table in it.
fn room(w: f64, d: f64, h: f64) -> Vec<Slab> {
    let mut slabs = room_slabs(w, d, h);
    slabs.push((
        [w / 2.0 - 0.5, d / 2.0 - 0.4, 0.0],
        [w / 2.0 + 0.5, d / 2.0 + 0.4, 0.75],
    ));
    slabs
}

/// Twelve cameras on a circle of radius `r` around (cx, cy) at 1.5 m, looking outwards,
/// down and up by turns.
fn ring(cx: f64, cy: f64, r: f64) -> Vec<FrameCamera> {
    (0..12)
        .map(|k| {
            let a = f64::from(k) * 30f64.to_radians();
            let eye = [cx + r * a.cos(), cy + r * a.sin(), 1.5];
            camera(
                eye,
                [
                    cx + 3.0 * a.cos(),
                    cy + 3.0 * a.sin(),
                    if k % 2 == 0 { 1.0 } else { 2.3 },
                ],
            )
        })
        .collect()
}

fn params() -> LayoutParams {
    // The test frames are 40 x 30: every depth pixel is sampled.
    LayoutParams {
        sample_step: 1,
        ..LayoutParams::default()
    }
}

/// The layout from `cams`' depth of `scene`, read in an output frame turned by `turn`
/// degrees about +z (the scene is rendered in the world frame).
fn estimate(cams: &[FrameCamera], scene: &[Slab], range: f64, turn: f64) -> Option<RoomLayout> {
    let maps: Vec<DepthMap> = cams.iter().map(|c| render(c, scene, range)).collect();
    let turned: Vec<FrameCamera> = cams
        .iter()
        .map(|c| FrameCamera {
            align: Matrix4::new_rotation(Vector3::z() * turn.to_radians()),
            ..*c
        })
        .collect();
    let frames: Vec<(&FrameCamera, &DepthMap)> = turned.iter().zip(&maps).collect();
    estimate_room(&frames, &params())
}

fn near(a: Option<f64>, b: f64, tol: f64) -> bool {
    a.is_some_and(|a| (a - b).abs() <= tol)
}

#[test]
fn a_box_room_is_found_with_its_floor_ceiling_and_walls() {
    let l = estimate(&ring(3.0, 2.5, 0.8), &room(6.0, 5.0, 2.7), 5.0, 0.0).expect("a layout");
    assert!(l.angle_deg.abs() < 0.5, "{l:?}");
    assert!(
        near(l.floor, 0.0, 0.03) && near(l.ceiling, 2.7, 0.03),
        "{l:?}"
    );
    assert!(near(l.u[0], 0.0, 0.03) && near(l.u[1], 6.0, 0.03), "{l:?}");
    assert!(near(l.v[0], 0.0, 0.03) && near(l.v[1], 5.0, 0.03), "{l:?}");
    assert!(l.range <= 5.0 && l.range > 2.5, "{l:?}");
    assert_eq!(l.faced, [true; 4]);
    // From the centre along +x the ray leaves through the wall at x = 6; upwards through
    // the ceiling; from outside the room there is no answer.
    let t = l
        .exit(&Point3::new(3.0, 2.5, 1.5), &Vector3::new(2.0, 0.0, 0.0))
        .expect("an exit");
    assert!((t - 1.5).abs() < 0.02, "t = {t}");
    assert!(near(
        l.exit(&Point3::new(3.0, 2.5, 1.5), &Vector3::z()),
        1.2,
        0.03
    ));
    assert_eq!(l.exit(&Point3::new(7.0, 2.5, 1.5), &Vector3::x()), None);
    // The x walls, at any height and position along them.
    let xs = l.walls_on_axis(0, &Point3::new(1.0, 4.0, 0.3));
    assert!(
        xs.len() == 2
            && xs.iter().any(|&x| x.abs() < 0.03)
            && xs.iter().any(|&x| (x - 6.0).abs() < 0.03),
        "{xs:?}"
    );
}

#[test]
fn a_turned_room_is_found_in_its_own_axes() {
    let l = estimate(&ring(3.0, 2.5, 0.8), &room(6.0, 5.0, 2.7), 5.0, 30.0).expect("a layout");
    assert!((l.angle_deg - 30.0).abs() < 0.5, "{l:?}");
    assert!(
        near(l.u[0], 0.0, 0.04)
            && near(l.u[1], 6.0, 0.04)
            && near(l.v[0], 0.0, 0.04)
            && near(l.v[1], 5.0, 0.04),
        "{l:?}"
    );
    // Its walls are 30 degrees off both output axes: none counts as an x or y wall.
    assert!(
        l.walls_on_axis(0, &Point3::origin()).is_empty()
            && l.walls_on_axis(1, &Point3::origin()).is_empty()
    );
}

#[test]
fn a_wall_no_frame_measured_stays_open() {
    // A 14 m long room, all cameras near its x = 0 end with a 5 m range: the far wall at
    // x = 14 is never read, so rays towards it have no end; the other sides are found.
    let cams = ring(2.0, 2.5, 0.6);
    let l = estimate(&cams, &room(14.0, 5.0, 2.7), 5.0, 0.0).expect("a layout");
    assert_eq!(l.u[1], None, "{l:?}");
    assert!(
        near(l.u[0], 0.0, 0.03) && near(l.v[0], 0.0, 0.03) && near(l.v[1], 5.0, 0.03),
        "{l:?}"
    );
    assert!(
        near(
            l.exit(&Point3::new(2.0, 2.5, 1.5), &-Vector3::x()),
            2.0,
            0.03
        ),
        "towards the wall that was found"
    );
    // Towards the open side no answer: the missing wall may be anywhere past what was
    // measured. A ray that meets the ceiling before it gets past the measured points
    // (x = 2.6 here; readings reach x ~ 7.7) ends there, and one that gets past them first
    // has no end.
    assert_eq!(l.exit(&Point3::new(2.0, 2.5, 1.5), &Vector3::x()), None);
    assert!(near(
        l.exit(&Point3::new(2.0, 2.5, 1.5), &Vector3::new(0.5, 0.0, 1.0)),
        1.2,
        0.03
    ));
    assert!(l.reach[0][1] > 6.0 && l.reach[0][1] < 8.0, "{l:?}");
    assert_eq!(
        l.exit(&Point3::new(2.0, 2.5, 1.5), &Vector3::new(10.0, 0.0, 1.0)),
        None
    );
    // No frames, or frames without readings: nothing to estimate.
    assert_eq!(estimate_room(&[], &params()), None);
    let blank = render(&cams[0], &room(14.0, 5.0, 2.7), 0.1);
    assert_eq!(estimate_room(&[(&cams[0], &blank)], &params()), None);
}

#[test]
fn walls_no_frame_faced_are_where_the_measured_surfaces_end() {
    // An 8 x 6 m room whose short walls (x = 0, x = 8) are left out of the rendering, as
    // if no frame had faced them: the floor and the long walls end at x = -0.1 and 8.1 in
    // every frame that looks that way.
    let mut scene = room(8.0, 6.0, 2.7);
    scene.drain(2..4);
    let l = estimate(&ring(4.0, 3.0, 1.5), &scene, 5.0, 0.0).expect("a layout");
    assert!(near(l.v[0], 0.0, 0.03) && near(l.v[1], 6.0, 0.03), "{l:?}");
    // Within the 40 x 30 test frames' last sampled floor row (a pixel spans ~10 cm there).
    assert!(near(l.u[0], -0.1, 0.25) && near(l.u[1], 8.1, 0.25), "{l:?}");
    assert_eq!(l.faced, [false, false, true, true], "{l:?}");
}

#[test]
fn a_frame_posed_far_away_does_not_blow_up_the_histograms() {
    let mut cams = ring(3.0, 2.5, 0.8);
    let scene = room(6.0, 5.0, 2.7);
    let maps: Vec<DepthMap> = cams.iter().map(|c| render(c, &scene, 5.0)).collect();
    // Its depth is real, its pose 10^6 km off (finite, so the frame counts as usable):
    // a histogram over that span would need 5 * 10^10 bins.
    cams[0].pose[(0, 3)] += 1.0e9;
    let frames: Vec<(&FrameCamera, &DepthMap)> = cams.iter().zip(&maps).collect();
    let l = estimate_room(&frames, &params()).expect("the heights are still fine");
    assert!(
        near(l.floor, 0.0, 0.03) && near(l.u[0], 0.0, 0.03) && l.u[1].is_none(),
        "{l:?}"
    );
}

#[test]
fn noisy_walls_are_placed_where_they_stand_not_in_their_noise_s_outer_tail() {
    // The room of the first test, its depth read with 3 cm of noise (a sum of four
    // uniforms, as wide as a consumer sensor's at 4 m). Seen from outside, the first layer
    // dense enough lies in the wall's outer tail.
    let cams = ring(3.0, 2.5, 0.8);
    let scene = room(6.0, 5.0, 2.7);
    let maps: Vec<DepthMap> = cams
        .iter()
        .enumerate()
        .map(|(f, c)| {
            let clean = render(c, &scene, 5.0);
            let (w, h) = (clean.width, clean.height);
            let mut i = 0u64;
            let mut noisy = Vec::with_capacity((w * h) as usize);
            for y in 0..h {
                for x in 0..w {
                    let d = clean.get(x, y);
                    let n: f64 = (0..4u64)
                        .map(|k| {
                            let v = (i * 4 + k + 1)
                                .wrapping_mul(0x9E37_79B9_7F4A_7C15)
                                .wrapping_add((f as u64 + 1).wrapping_mul(0xBF58_476D_1CE4_E5B9));
                            ((v >> 11) as f64 / (1u64 << 53) as f64) - 0.5
                        })
                        .sum();
                    i += 1;
                    let z = f64::from(d) + 0.03 * 1000.0 * n * 3f64.sqrt();
                    noisy.push(if d == 0 { 0 } else { z.round().max(1.0) as u16 });
                }
            }
            DepthMap::new(w, h, noisy)
        })
        .collect();
    let frames: Vec<(&FrameCamera, &DepthMap)> = cams.iter().zip(&maps).collect();
    let l = estimate_room(&frames, &params()).expect("a layout");
    for (got, want) in [(l.u[0], 0.0), (l.u[1], 6.0), (l.v[0], 0.0), (l.v[1], 5.0)] {
        assert!(near(got, want, 0.008), "{got:?} against {want}: {l:?}");
    }
}

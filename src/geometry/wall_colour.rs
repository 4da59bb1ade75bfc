//! Colour where depth cannot tell an object from its wall (ours). Far from the camera a
//! wall's points spread over a band several centimetres thick, and whatever stands within
//! that band of it (a lamp's shade, a bin in the corner) is cut with the wall by
//! [`super::cut_room_walls`]. The wall's own colours are known from the points around the
//! mask that lie in the band; the object's from its points clear of every band. A point in
//! the band whose colour is unlike every wall colour, and nearer to the object's, is the
//! object's.

/// Colours kept of each side (evenly spaced over the input): enough for the few colours an
/// object shows, few enough that comparing every band point with them costs nothing.
const SAMPLES: usize = 64;

/// The least spread (RGB units) a wall's colours are taken to have: an 8-bit camera's noise
/// and JPEG's blocks move a colour by about this much even on a wall of one paint.
const MIN_SPREAD: f32 = 6.0;

/// One wall's colours against the object's.
#[derive(Debug, Clone)]
pub(crate) struct ColourSplit {
    wall: Vec<[f32; 3]>,
    object: Vec<[f32; 3]>,
    /// How far a wall colour may lie from the nearest other one (the 90th percentile over
    /// the wall's samples): shading, sensor noise and compression.
    spread: f32,
}

fn subsample(colours: &[[u8; 3]]) -> Vec<[f32; 3]> {
    let step = colours.len().div_ceil(SAMPLES).max(1);
    colours
        .iter()
        .step_by(step)
        .map(|c| c.map(f32::from))
        .collect()
}

fn dist(a: [f32; 3], b: [f32; 3]) -> f32 {
    let d = [a[0] - b[0], a[1] - b[1], a[2] - b[2]];
    (d[0] * d[0] + d[1] * d[1] + d[2] * d[2]).sqrt()
}

/// Distance from `c` to the nearest of `set`, leaving out index `skip`.
fn nearest(c: [f32; 3], set: &[[f32; 3]], skip: Option<usize>) -> f32 {
    set.iter()
        .enumerate()
        .filter(|&(i, _)| Some(i) != skip)
        .map(|(_, &s)| dist(c, s))
        .fold(f32::INFINITY, f32::min)
}

impl ColourSplit {
    /// `wall`: colours of the wall's own points (outside the mask, within its band);
    /// `object`: of the object's points clear of every band. `None` when either holds fewer
    /// than `min` colours: then colour says nothing.
    pub(crate) fn new(wall: &[[u8; 3]], object: &[[u8; 3]], min: usize) -> Option<Self> {
        let min = min.max(2);
        if wall.len() < min || object.len() < min {
            return None;
        }
        let (wall, object) = (subsample(wall), subsample(object));
        let mut gaps: Vec<f32> = (0..wall.len())
            .map(|i| nearest(wall[i], &wall, Some(i)))
            .collect();
        gaps.sort_by(f32::total_cmp);
        let spread = gaps[(gaps.len() * 9 / 10).min(gaps.len() - 1)];
        Some(Self {
            wall,
            object,
            spread,
        })
    }

    /// Is `c` the object's: farther from every wall colour than twice the wall's colours
    /// lie from each other (at least [`MIN_SPREAD`]), and nearer to one of the object's?
    pub(crate) fn is_object(&self, c: [u8; 3]) -> bool {
        let c = c.map(f32::from);
        let to_wall = nearest(c, &self.wall, None);
        to_wall > 2.0 * self.spread.max(MIN_SPREAD) && nearest(c, &self.object, None) < to_wall
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    /// A grey wall lit unevenly (120–160) with a little noise.
    fn wall() -> Vec<[u8; 3]> {
        (0..400)
            .map(|i| {
                let g = 120 + (i % 41) as u8 + (i % 3) as u8;
                [g, g, g.saturating_sub(4)]
            })
            .collect()
    }

    #[test]
    fn a_yellow_shade_before_a_grey_wall_is_told_apart_and_a_grey_one_is_not() {
        let yellow: Vec<[u8; 3]> = (0..200).map(|i| [200 + (i % 9) as u8, 170, 40]).collect();
        let s = ColourSplit::new(&wall(), &yellow, 12).expect("enough colours");
        assert!(s.is_object([204, 168, 45]));
        // The wall's colours, its darkest and lightest, stay the wall's.
        for c in [[121, 121, 117], [140, 140, 136], [161, 161, 157]] {
            assert!(!s.is_object(c), "{c:?}");
        }
        // An object the wall's colour: nothing is the object's by colour.
        let grey = wall()[..200].to_vec();
        let s = ColourSplit::new(&wall(), &grey, 12).expect("enough colours");
        assert!(grey.iter().all(|&c| !s.is_object(c)));
        // A colour unlike both, nearer the wall: not the object's either.
        let s = ColourSplit::new(&wall(), &yellow, 12).expect("enough colours");
        assert!(!s.is_object([90, 90, 130]));
    }

    #[test]
    fn a_shade_within_the_band_of_its_wall_keeps_its_points_by_colour() {
        use crate::geometry::test_grid::grid;
        use crate::geometry::{cut_room_walls, ColourLookup, SupportParams};
        use nalgebra::Point3;
        let room = crate::geometry::test_scene::room_box(0.0, 4.0, 3.0, 2.5);
        // The wall x = 0 behind the mask and around it; a shade's side from 2 cm before
        // the wall out to 30 cm, its first 2–4 cm inside the wall's band (one layer).
        let patch = grid((0.8, 1.25), (0.0, 1.5), 0.01, |y, z| Point3::new(0.0, y, z));
        let shade = grid((0.02, 0.3), (1.0, 1.3), 0.01, |x, z| Point3::new(x, 1.0, z));
        let in_band = shade.iter().filter(|q| q.x <= 0.04 + 1e-9).count();
        let ctx: Vec<Point3<f64>> =
            grid((0.5, 1.6), (0.0, 2.0), 0.02, |y, z| Point3::new(0.0, y, z))
                .into_iter()
                .filter(|q| !(q.y > 0.78 && q.y < 1.27 && q.z < 1.52))
                .collect();
        let mut mask = patch.clone();
        mask.extend(&shade);
        // The frame's colours: an unevenly lit grey wall; the shade yellow.
        let grey = |q: &Point3<f64>| {
            let g = 120 + ((q.y * 100.0 + q.z * 700.0).round() as usize % 41) as u8;
            [g, g, g - 4]
        };
        let yellow = |q: &Point3<f64>| {
            if q.x < 0.01 {
                grey(q)
            } else {
                [200 + ((q.z * 100.0).round() as usize % 9) as u8, 170, 40]
            }
        };
        let (by_yellow, by_grey) = (
            |pts: &[Point3<f64>]| pts.iter().map(yellow).collect::<Vec<_>>(),
            |pts: &[Point3<f64>]| pts.iter().map(grey).collect::<Vec<_>>(),
        );
        let p = SupportParams::default();
        let (kept, cuts) = cut_room_walls(&mask, &ctx, &room, Some(&by_yellow), &p);
        assert_eq!(kept.len(), shade.len(), "{cuts:?}");
        assert_eq!(cuts[0].kept_by_colour, in_band, "{cuts:?}");
        assert!(in_band > 0);
        // Without colours, or switched off, or a shade the wall's grey: its band points go.
        let off = SupportParams {
            room_wall_colour: false,
            ..SupportParams::default()
        };
        let cases: [(Option<ColourLookup>, &SupportParams); 3] =
            [(None, &p), (Some(&by_yellow), &off), (Some(&by_grey), &p)];
        for (look, p) in cases {
            let (kept, cuts) = cut_room_walls(&mask, &ctx, &room, look, p);
            assert_eq!(kept.len(), shade.len() - in_band, "{cuts:?}");
        }
    }

    #[test]
    fn too_few_colours_say_nothing() {
        let yellow = vec![[200u8, 170, 40]; 5];
        assert!(ColourSplit::new(&wall(), &yellow, 12).is_none());
        assert!(ColourSplit::new(&yellow, &wall(), 12).is_none());
    }
}

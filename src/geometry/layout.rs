//! Room layout prior (ours, not the paper's): the room as a box — floor, ceiling and two
//! pairs of walls at right angles, turned about the vertical — estimated from the depth of
//! all frames.
//!
//! It answers one question no measurement can: where a viewing ray that no frame ever got
//! a reading for ends. A window or picture on a wall that every camera saw from beyond the
//! sensor's range has no depth anywhere, but the wall it hangs on was measured nearer its
//! corners, and the ray through the object's pixels ends where it leaves the room.
//!
//! Estimation, on points sampled from every frame's depth (output frame, +z up):
//! 1. floor and ceiling: the lowest and highest height layer that spreads over
//!    `min_spread` along both horizontal axes (the ceiling only above every camera);
//! 2. orientation: the turn about +z (0–90°) that makes the horizontal coordinates of the
//!    points between floor and ceiling most peaked (walls become spikes of a histogram);
//! 3. walls: along each turned axis, from each end inwards, the first layer holding
//!    `min_points` that spreads over `min_spread` along the wall; it must lie beyond every
//!    camera (the cameras are inside the room). Nothing is measured behind a wall, so the
//!    outermost such layer is the wall, however little of it was measured (centred where
//!    its readings are densest: see [`outer_layer`]). A wall that no frame faced (a scan
//!    circling the room and looking across it sees the walls along its long side only
//!    beyond range) is placed where the measured points end along that axis: the walls
//!    running up to it, and the floor, end there in `end_frames` frames or more (the range
//!    ends each frame's points at a different place).
//!
//! A side that was not found stays open: a ray leaving through it has no end.

use nalgebra::{Matrix4, Point3, Vector3};
use serde::{Deserialize, Serialize};
use std::collections::BTreeMap;

use super::camera::{is_finite_matrix, transform_point};
use super::{DepthMap, FrameCamera};

/// Settings of [`estimate_room`] and of its use.
#[derive(Debug, Clone, PartialEq, Serialize, Deserialize)]
#[serde(default, deny_unknown_fields)]
pub struct LayoutParams {
    /// Estimate the room and use it for objects flat against a wall (see the agent).
    pub enabled: bool,
    /// Side (depth pixels) of the blocks sampled: one point per block, at its median depth.
    pub sample_step: u32,
    /// At most this many sampled points are used (evenly thinned).
    pub max_points: usize,
    /// Histogram bin (m); a layer is three bins thick.
    pub bin: f64,
    /// Points a layer needs.
    pub min_points: usize,
    /// Spread (m, 10th–90th percentile) a layer needs along the surface.
    pub min_spread: f64,
    /// The sensor's range is this quantile of all readings.
    pub range_quantile: f64,
    /// The room's box is used only for a region whose depth pixels are less than this share
    /// read or filled from other frames: an object that was measured is not mixed with
    /// points put on its wall.
    pub max_measured: f64,
    /// A ray without any reading is ended on the room's box only when it leaves the room at
    /// least `range - range_margin` deep: nearer, a missing reading is no sign of distance
    /// (a dark or glossy surface, a grazing angle) and the object may stand anywhere.
    pub range_margin: f64,
    /// Frames whose points must end at the same place (within a layer) for a wall no frame
    /// faced to be placed there.
    pub end_frames: usize,
    /// Depth (m) given to a flat object whose points lie on its wall (no frame resolved
    /// its front from the wall), unless `class_depth` names its class.
    pub flat_depth: f64,
    /// Depth (m) by class for the same case: the usual thickness of the thing itself (a
    /// picture's frame, a door's leaf), matched like the support classes (whole name or
    /// last word, singular or plural).
    pub class_depth: BTreeMap<String, f64>,
    /// Frames that saw a flat object only beyond their sensor's range (no reading where its
    /// points lie, and their ray leaves the room there) join its ensemble, their empty
    /// pixels put on the room's box, also when the chosen view measured it (a window seen
    /// once from close by and otherwise from across the room). Off: only when the chosen
    /// view's pixels were themselves put on the room's box.
    pub views_beyond_range: bool,
}

impl LayoutParams {
    /// The depth given to a flat object of `class` lying on its wall.
    pub fn flat_depth_for(&self, class: &str) -> f64 {
        self.class_depth
            .iter()
            .find(|(c, _)| super::support::class_in(std::slice::from_ref(*c), class))
            .map_or(self.flat_depth, |(_, d)| *d)
    }
}

impl Default for LayoutParams {
    fn default() -> Self {
        // Framed pictures and boards are a few centimetres deep; doors and windows keep
        // `flat_depth`.
        let class_depth = [
            ("picture", 0.03),
            ("painting", 0.03),
            ("poster", 0.01),
            ("photo", 0.02),
            ("frame", 0.03),
            ("mirror", 0.03),
            ("whiteboard", 0.02),
            ("blackboard", 0.02),
            ("board", 0.02),
            ("sign", 0.01),
        ]
        .into_iter()
        .map(|(c, d)| (c.to_string(), d))
        .collect();
        Self {
            enabled: true,
            sample_step: 8,
            max_points: 60_000,
            bin: 0.02,
            min_points: 40,
            min_spread: 1.0,
            range_quantile: 0.999,
            max_measured: 0.5,
            range_margin: 0.3,
            end_frames: 2,
            flat_depth: 0.05,
            class_depth,
            views_beyond_range: true,
        }
    }
}

/// The room's box. Horizontal coordinates are turned by `angle_deg` about +z: `u` runs
/// along (cos a, sin a), `v` along (−sin a, cos a).
#[derive(Debug, Clone, PartialEq, Serialize)]
pub struct RoomLayout {
    pub angle_deg: f64,
    /// Wall coordinates on u and v (low, high); `None` where no wall was found.
    pub u: [Option<f64>; 2],
    pub v: [Option<f64>; 2],
    /// Which of the walls u low, u high, v low, v high were measured facing a camera; the
    /// others are where the measured points end along that axis.
    pub faced: [bool; 4],
    pub floor: Option<f64>,
    pub ceiling: Option<f64>,
    /// The sensor's range (m), from the readings.
    pub range: f64,
    /// How far the measured points reach on u, v and z (low, high): an open side lies at
    /// least that far.
    pub reach: [[f64; 2]; 3],
    /// Points sampled (layers and the turn use at most `max_points` of them).
    pub points: usize,
}

/// A sampled point with its surface normal.
struct Sample {
    p: Point3<f64>,
    n: Vector3<f64>,
    /// The frame it was read in.
    frame: usize,
}

/// A frame's samples: the median depth of each `step` x `step` block of depth pixels (at
/// least half of them read), with the normal from the neighbouring blocks (samples where a
/// neighbour is missing or lies across a depth edge are left out). Also each block's
/// largest reading, and the camera centre. Medians and a block-wide baseline keep the
/// normals usable at the sensor's far end, where single readings are centimetres off.
fn sample_frame(
    cam: &FrameCamera,
    depth: &DepthMap,
    step: u32,
    frame: usize,
    out: &mut Vec<Sample>,
    readings: &mut Vec<f64>,
) -> Option<Point3<f64>> {
    cam.check_depth(depth).ok()?;
    let m = cam.cam_to_out();
    if !is_finite_matrix(&m) {
        return None;
    }
    let step = step.max(1);
    let (bw, bh) = (
        (depth.width / step) as usize,
        (depth.height / step) as usize,
    );
    let mut grid: Vec<Option<(f64, Point3<f64>)>> = vec![None; bw * bh];
    let mut block = Vec::with_capacity((step * step) as usize);
    for by in 0..bh {
        for bx in 0..bw {
            block.clear();
            let (x0, y0) = (bx as u32 * step, by as u32 * step);
            for y in y0..y0 + step {
                block.extend((x0..x0 + step).map(|x| depth.get(x, y)).filter(|&d| d > 0));
            }
            if 2 * block.len() < (step * step) as usize {
                continue;
            }
            let mid = block.len() / 2;
            let z = f64::from(*block.select_nth_unstable(mid).1) / 1000.0;
            readings.push(f64::from(block.iter().copied().max().unwrap_or(0)) / 1000.0);
            let (u, v) = super::depth_fill::color_pixel(
                cam,
                f64::from(x0) + f64::from(step) / 2.0 - 0.5,
                f64::from(y0) + f64::from(step) / 2.0 - 0.5,
            );
            grid[by * bw + bx] = Some((z, transform_point(&m, &cam.color.unproject(u, v, z))));
        }
    }
    let at = |x: usize, y: usize| grid[y * bw + x];
    for y in 1..bh.saturating_sub(1) {
        for x in 1..bw.saturating_sub(1) {
            let Some((z, p)) = at(x, y) else { continue };
            let (Some(l), Some(r), Some(u), Some(d)) =
                (at(x - 1, y), at(x + 1, y), at(x, y - 1), at(x, y + 1))
            else {
                continue;
            };
            if [l, r, u, d].iter().any(|q| (q.0 - z).abs() > 0.1 * z) {
                continue;
            }
            let n = (r.1 - l.1).cross(&(d.1 - u.1));
            if let Some(n) = n.try_normalize(1e-12) {
                out.push(Sample { p, n, frame });
            }
        }
    }
    Some(cam.centre())
}

/// Quantile `q` of `v` (sorted in place); `None` when empty.
fn quantile(v: &mut [f64], q: f64) -> Option<f64> {
    if v.is_empty() {
        return None;
    }
    v.sort_by(f64::total_cmp);
    Some(v[((v.len() - 1) as f64 * q.clamp(0.0, 1.0)).round() as usize])
}

fn spread(mut v: Vec<f64>) -> f64 {
    match (quantile(&mut v, 0.1), quantile(&mut v, 0.9)) {
        (Some(a), Some(b)) => b - a,
        _ => 0.0,
    }
}

/// The outermost layer of `coord` seen from the low end (`from_low`) or the high end:
/// three bins holding `min_points` whose points spread over `min_spread` along each of the
/// `lateral` coordinates, lying beyond `limit` (outside the cameras). Where the points
/// within the layer's thickness of its median are densest (in [`centre::MODE_WIDTH`]).
fn outer_layer(
    coord: &[f64],
    lateral: &[&[f64]],
    from_low: bool,
    limit: f64,
    p: &LayoutParams,
) -> Option<f64> {
    let (lo, hi) = coord
        .iter()
        .fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), &c| {
            (a.min(c), b.max(c))
        });
    // A wild (finite) pose can spread the points over kilometres: no histogram then.
    if !(lo.is_finite() && hi.is_finite()) || p.bin <= 0.0 || (hi - lo) / p.bin > MAX_BINS {
        return None;
    }
    let n = ((hi - lo) / p.bin).floor() as usize + 1;
    let bin_of = |c: f64| (((c - lo) / p.bin).floor() as usize).min(n - 1);
    let mut counts = vec![0usize; n];
    for &c in coord {
        counts[bin_of(c)] += 1;
    }
    let order: Vec<usize> = if from_low {
        (0..n).collect()
    } else {
        (0..n).rev().collect()
    };
    for i in order {
        let centre = lo + (i as f64 + 0.5) * p.bin;
        if (from_low && centre > limit) || (!from_low && centre < limit) {
            return None;
        }
        let window = i.saturating_sub(1)..=(i + 1).min(n - 1);
        if counts[window.clone()].iter().sum::<usize>() < p.min_points || counts[i] == 0 {
            continue;
        }
        let members: Vec<usize> = (0..coord.len())
            .filter(|&k| window.contains(&bin_of(coord[k])))
            .collect();
        if lateral
            .iter()
            .all(|l| spread(members.iter().map(|&k| l[k]).collect()) >= p.min_spread)
        {
            let mut c: Vec<f64> = members.iter().map(|&k| coord[k]).collect();
            // Found from outside, in the tail of its noise on that side, and holding what
            // hangs on the wall as well: centred on its densest part.
            let start = quantile(&mut c, 0.5)?;
            return Some(centre::wall_centre(coord, lateral, start, p));
        }
    }
    None
}

/// How peaked the turned horizontal coordinates are at `angle` (radians): the sum of
/// squared bin counts along both turned axes.
fn peakedness(xy: &[[f64; 2]], angle: f64, bin: f64) -> f64 {
    let (s, c) = angle.sin_cos();
    let mut total = 0.0;
    for axis in 0..2 {
        let mut counts: std::collections::HashMap<i64, usize> = std::collections::HashMap::new();
        for p in xy {
            let t = if axis == 0 {
                c * p[0] + s * p[1]
            } else {
                -s * p[0] + c * p[1]
            };
            *counts.entry((t / bin).floor() as i64).or_default() += 1;
        }
        total += counts.values().map(|&n| (n * n) as f64).sum::<f64>();
    }
    total
}

/// Estimate the room's box from every frame's depth (frames whose depth or pose is
/// unusable are skipped). `None` when there are too few points for any layer.
pub fn estimate_room(frames: &[(&FrameCamera, &DepthMap)], p: &LayoutParams) -> Option<RoomLayout> {
    let (mut samples, mut readings, mut eyes) = (Vec::new(), Vec::new(), Vec::new());
    for (i, (cam, depth)) in frames.iter().enumerate() {
        if let Some(e) = sample_frame(cam, depth, p.sample_step, i, &mut samples, &mut readings) {
            eyes.push(e);
        }
    }

    if samples.len() < p.min_points || eyes.is_empty() {
        return None;
    }
    // Frame ends (`frame_ends`) are taken on the full samples: thinning moves them.
    let full = samples;
    let samples: Vec<&Sample> = full
        .iter()
        .step_by(full.len().div_ceil(p.max_points.max(1)).max(1))
        .collect();
    let range = quantile(&mut readings, p.range_quantile)?;
    let ext = |v: &mut dyn Iterator<Item = f64>| {
        v.fold((f64::INFINITY, f64::NEG_INFINITY), |(a, b), x| {
            (a.min(x), b.max(x))
        })
    };
    // Floor and ceiling from the surfaces facing up or down.
    let level: Vec<&Sample> = samples
        .iter()
        .copied()
        .filter(|s| s.n.z.abs() >= FACING)
        .collect();
    let (xs, ys, zs): (Vec<f64>, Vec<f64>, Vec<f64>) = (
        level.iter().map(|s| s.p.x).collect(),
        level.iter().map(|s| s.p.y).collect(),
        level.iter().map(|s| s.p.z).collect(),
    );
    let (eye_lo, eye_hi) = ext(&mut eyes.iter().map(|e| e.z));
    let floor = outer_layer(&zs, &[&xs, &ys], true, eye_lo, p);
    let ceiling = outer_layer(&zs, &[&xs, &ys], false, eye_hi, p);
    // Walls from the surfaces facing sideways: the turn that makes their horizontal
    // coordinates most peaked, then each turned axis's outermost layers facing along it.
    let upright: Vec<&Sample> = samples
        .iter()
        .copied()
        .filter(|s| s.n.z.abs() <= 1.0 - FACING)
        .collect();
    let xy: Vec<[f64; 2]> = {
        let k = upright.len().div_ceil(20_000).max(1);
        upright.iter().step_by(k).map(|s| [s.p.x, s.p.y]).collect()
    };
    let best = |angles: &mut dyn Iterator<Item = f64>| {
        angles
            .map(|a| (a, peakedness(&xy, a.to_radians(), p.bin)))
            .max_by(|a, b| a.1.total_cmp(&b.1))
            .map(|(a, _)| a)
    };
    let coarse = best(&mut (-45..45).map(f64::from))?;
    let angle_deg = best(&mut (-10..=10).map(|k| coarse + 0.1 * f64::from(k)))?;
    let frame_ends = frame_ends(&full, frames.len(), angle_deg);
    let (s, c) = angle_deg.to_radians().sin_cos();
    let turn = |x: f64, y: f64| (c * x + s * y, -s * x + c * y);
    let mut walls: [[Option<(f64, bool)>; 2]; 2] = [[None, None], [None, None]];
    for (axis, sides) in walls.iter_mut().enumerate() {
        let facing: Vec<(f64, f64)> = upright
            .iter()
            .filter(|q| {
                let (nu, nv) = turn(q.n.x, q.n.y);
                (if axis == 0 { nu } else { nv }).abs() >= FACING
            })
            .map(|q| {
                let (u, v) = turn(q.p.x, q.p.y);
                if axis == 0 {
                    (u, v)
                } else {
                    (v, u)
                }
            })
            .collect();
        let (along, lateral): (Vec<f64>, Vec<f64>) = facing.into_iter().unzip();
        let (lo, hi) = ext(&mut eyes.iter().map(|e| {
            let (u, v) = turn(e.x, e.y);
            if axis == 0 {
                u
            } else {
                v
            }
        }));
        // A wall no frame faced (the cameras looked along it, and it was beyond range where
        // they faced it) still ends what the frames measured: where the walls along it and
        // the floor meet it. Several frames must end there: the range ends each frame's
        // points somewhere else, a wall ends them all at the same place.
        let ends = &frame_ends[axis];
        let end = |mut e: Vec<f64>, limit: f64| {
            e.sort_by(f64::total_cmp);
            let first = *e.first()?;
            let agree: Vec<f64> = e
                .into_iter()
                .take_while(|x| *x <= first + 3.0 * p.bin)
                .collect();
            (agree.len() >= p.end_frames.max(1) && first < limit)
                .then(|| (agree[agree.len() / 2], false))
        };
        let end_lo = || end(ends.iter().map(|e| e.0).collect(), lo);
        let end_hi = || end(ends.iter().map(|e| -e.1).collect(), -hi).map(|(x, f)| (-x, f));
        *sides = [
            outer_layer(&along, &[&lateral], true, lo, p)
                .map(|w| (w, true))
                .or_else(end_lo),
            outer_layer(&along, &[&lateral], false, hi, p)
                .map(|w| (w, true))
                .or_else(end_hi),
        ];
    }
    let [u, v] = walls;
    let faced = [
        u[0].is_some_and(|w| w.1),
        u[1].is_some_and(|w| w.1),
        v[0].is_some_and(|w| w.1),
        v[1].is_some_and(|w| w.1),
    ];
    let (u, v) = (u.map(|w| w.map(|w| w.0)), v.map(|w| w.map(|w| w.0)));
    let reach = [0, 1, 2].map(|axis| {
        let ends = &frame_ends[axis];
        ends.iter()
            .fold([f64::INFINITY, f64::NEG_INFINITY], |[a, b], e| {
                [a.min(e.0), b.max(e.1)]
            })
    });
    Some(RoomLayout {
        angle_deg,
        u,
        v,
        faced,
        floor,
        ceiling,
        reach,
        points: full.len(),
        range,
    })
}

/// Where each frame's samples end (see [`END_RANK`]) along u and v (turned by `angle`
/// degrees) and z: for each of the three, one (low, high) pair per frame with enough
/// samples, in frame order.
fn frame_ends(samples: &[Sample], frames: usize, angle: f64) -> [Vec<(f64, f64)>; 3] {
    let (s, c) = angle.to_radians().sin_cos();
    let mut per_frame: Vec<[Vec<f64>; 3]> = vec![[Vec::new(), Vec::new(), Vec::new()]; frames];
    for q in samples {
        per_frame[q.frame][0].push(c * q.p.x + s * q.p.y);
        per_frame[q.frame][1].push(-s * q.p.x + c * q.p.y);
        per_frame[q.frame][2].push(q.p.z);
    }
    let mut ends: [Vec<(f64, f64)>; 3] = [Vec::new(), Vec::new(), Vec::new()];
    for f in per_frame.iter_mut() {
        for (axis, v) in f.iter_mut().enumerate() {
            if v.len() > 2 * END_RANK {
                v.sort_by(f64::total_cmp);
                ends[axis].push((v[END_RANK], v[v.len() - 1 - END_RANK]));
            }
        }
    }
    ends
}

/// A frame's end along an axis is its sample of this rank from that end (0: the last; a
/// stray reading is caught by asking several frames to agree).
const END_RANK: usize = 0;

/// Most bins a layer histogram may have (2 km at 2 cm).
const MAX_BINS: f64 = 100_000.0;

/// |cos| between a normal and an axis for the surface to count as facing along it.
const FACING: f64 = 0.8;

impl RoomLayout {
    /// (u, v) of a horizontal position or direction: x, y turned by the room's angle.
    pub(crate) fn turn(&self, x: f64, y: f64) -> (f64, f64) {
        let (s, c) = self.angle_deg.to_radians().sin_cos();
        (c * x + s * y, -s * x + c * y)
    }

    /// The side of the room nearest to `p` among those found, as (side, signed distance):
    /// sides 0–3 are the walls u low, u high, v low, v high, 4 the floor, 5 the ceiling; the
    /// distance is positive inside the room and negative beyond that side. `None` when no
    /// side was found.
    pub fn nearest_side(&self, p: &Point3<f64>) -> Option<(usize, f64)> {
        let (pu, pv) = self.turn(p.x, p.y);
        let dists = [
            self.u[0].map(|l| pu - l),
            self.u[1].map(|h| h - pu),
            self.v[0].map(|l| pv - l),
            self.v[1].map(|h| h - pv),
            self.floor.map(|f| p.z - f),
            self.ceiling.map(|c| c - p.z),
        ];
        dists
            .iter()
            .enumerate()
            .filter_map(|(i, d)| d.map(|d| (i, d)))
            .min_by(|a, b| a.1.total_cmp(&b.1))
    }

    /// The parameter t at which the ray `o + t d` (t > 0) leaves the box through a side
    /// that was found; `None` when `o` is outside the box or the ray may leave through an
    /// open side first (it gets past the measured points' `reach` on that side before).
    pub fn exit(&self, o: &Point3<f64>, d: &Vector3<f64>) -> Option<f64> {
        let (ou, ov) = self.turn(o.x, o.y);
        let (du, dv) = self.turn(d.x, d.y);
        let sides = [
            (ou, du, self.u, self.reach[0]),
            (ov, dv, self.v, self.reach[1]),
            (o.z, d.z, [self.floor, self.ceiling], self.reach[2]),
        ];
        // Through the sides found; an open side is no further than... unknown, but at least
        // as far as anything measured: the ray is inside the room until it gets there.
        let (mut t_exit, mut t_known) = (f64::INFINITY, f64::INFINITY);
        for (oc, dc, [lo, hi], [rlo, rhi]) in sides {
            if lo.is_some_and(|l| oc < l) || hi.is_some_and(|h| oc > h) {
                return None;
            }
            let (bound, reach) = if dc > 1e-12 {
                (hi, rhi)
            } else if dc < -1e-12 {
                (lo, rlo)
            } else {
                continue;
            };
            match bound {
                Some(b) => t_exit = t_exit.min((b - oc) / dc),
                None => t_known = t_known.min((reach - oc) / dc),
            }
        }
        (t_exit.is_finite() && t_exit > 0.0 && t_exit <= t_known).then_some(t_exit)
    }

    /// Camera depth at which the viewing ray through colour pixel (u, v) of `cam` leaves
    /// the room (`None`: open side, bad pose, or the camera outside the room).
    pub fn exit_depth(
        &self,
        cam: &FrameCamera,
        cam_to_out: &Matrix4<f64>,
        u: f64,
        v: f64,
    ) -> Option<f64> {
        let o = transform_point(cam_to_out, &Point3::origin());
        let d = transform_point(cam_to_out, &cam.color.unproject(u, v, 1.0)) - o;
        self.exit(&o, &d)
    }

    /// Would a missing reading at that depth be explained by the sensor's range?
    pub fn beyond_range(&self, depth: f64, p: &LayoutParams) -> bool {
        depth >= self.range - p.range_margin
    }

    /// The walls crossing output axis `axis` (0 = x, 1 = y) near `at`: each wall whose
    /// normal is within 10° of the axis, as its coordinate on that axis at `at`'s position
    /// along the wall.
    pub fn walls_on_axis(&self, axis: usize, at: &Point3<f64>) -> Vec<f64> {
        let a = self.angle_deg.to_radians();
        let (s, c) = a.sin_cos();
        let mut out = Vec::new();
        // The u walls have normal (c, s); the v walls (−s, c).
        for (normal, walls) in [([c, s], self.u), ([-s, c], self.v)] {
            let along = normal[axis];
            if along.abs() < 10f64.to_radians().cos() {
                continue;
            }
            let other = 1 - axis;
            for w in walls.into_iter().flatten() {
                // normal · (x, y) = w, solved for the coordinate on `axis`.
                out.push((w - normal[other] * at[other]) / along);
            }
        }
        out
    }
}

mod centre;
#[cfg(test)]
mod tests;

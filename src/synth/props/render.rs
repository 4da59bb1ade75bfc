//! Ray caster of the props family: colour (two ceiling lights, Lambert shading, 3D value
//! noise texture), depth and instance ids. Rays go through integer pixel coordinates of
//! the given intrinsics with camera-z = 1, so the hit parameter is the depth itself.

use super::layout::PropWorld;
use super::models::Mat;
use super::prim::Shape;
use crate::geometry::Intrinsics;
use crate::synth::render::{hash, ColorFrame, DepthFrame};
use nalgebra::Matrix4;

/// Entries of the linear -> display (gamma 2.2) lookup table.
const GAMMA_LUT: usize = 4096;

struct Prim {
    shape: Shape,
    /// Index into the object list.
    obj: usize,
    albedo: [f64; 3],
    /// Conservative bounds, for the per-frame screen rectangle.
    lo: [f64; 3],
    hi: [f64; 3],
}

/// Immutable scene description shared by all frame renders.
pub(crate) struct Renderer {
    prims: Vec<Prim>,
    ids: Vec<u16>,
    room: [f64; 3],
    lights: [[f64; 3]; 2],
    wall: [f64; 3],
    floor: [f64; 3],
    tiles: bool,
    seed: u64,
}

struct RayHit {
    t: f64,
    n: [f64; 3],
    /// Primitive index, or None for the room shell.
    prim: Option<usize>,
}

fn albedo(m: Mat, main: [f64; 3]) -> [f64; 3] {
    match m {
        Mat::Main => main,
        Mat::Trim => main.map(|c| c * 0.7),
        Mat::Metal => [0.45, 0.45, 0.47],
        Mat::Screen => [0.02, 0.025, 0.03],
        Mat::Leaf => [0.07, 0.3, 0.06],
        Mat::Glass => [0.55, 0.65, 0.72],
        Mat::Wood => [0.2, 0.11, 0.05],
    }
}

impl Renderer {
    pub fn new(world: &PropWorld, seed: u64) -> Self {
        let mut prims = Vec::new();
        for (i, o) in world.objects.iter().enumerate() {
            for (s, m) in &o.shapes {
                let b = s.aabb();
                prims.push(Prim {
                    shape: *s,
                    obj: i,
                    albedo: albedo(*m, o.rgb),
                    lo: b.min,
                    hi: b.max,
                });
            }
        }
        let (w, d, h) = world.size;
        Renderer {
            prims,
            ids: world.objects.iter().map(|o| o.id as u16).collect(),
            room: [w, d, h],
            lights: [[w * 0.3, d * 0.4, h - 0.1], [w * 0.72, d * 0.62, h - 0.1]],
            wall: world.wall_rgb,
            floor: world.floor_rgb,
            tiles: world.tiles,
            seed,
        }
    }

    /// Screen rectangle [u0, u1, v0, v1] of a primitive's bounds; None when off-screen.
    fn rect(r: &[[f64; 3]; 3], eye: &[f64; 3], k: &Intrinsics, p: &Prim) -> Option<[i64; 4]> {
        let (w, h) = (k.width as i64, k.height as i64);
        let (mut lo, mut hi) = ([f64::INFINITY; 2], [f64::NEG_INFINITY; 2]);
        for c in 0..8 {
            let q = [
                if c & 1 == 0 { p.lo[0] } else { p.hi[0] },
                if c & 2 == 0 { p.lo[1] } else { p.hi[1] },
                if c & 4 == 0 { p.lo[2] } else { p.hi[2] },
            ];
            let dv = [q[0] - eye[0], q[1] - eye[1], q[2] - eye[2]];
            let cam = [0, 1, 2].map(|j| r[0][j] * dv[0] + r[1][j] * dv[1] + r[2][j] * dv[2]);
            if cam[2] < 0.02 {
                return Some([0, w - 1, 0, h - 1]);
            }
            let u = k.fx * cam[0] / cam[2] + k.cx;
            let v = k.fy * cam[1] / cam[2] + k.cy;
            lo = [lo[0].min(u), lo[1].min(v)];
            hi = [hi[0].max(u), hi[1].max(v)];
        }
        let b = [
            lo[0].floor() as i64 - 1,
            hi[0].ceil() as i64 + 1,
            lo[1].floor() as i64 - 1,
            hi[1].ceil() as i64 + 1,
        ];
        if b[1] < 0 || b[0] >= w || b[3] < 0 || b[2] >= h {
            return None;
        }
        Some([b[0].max(0), b[1].min(w - 1), b[2].max(0), b[3].min(h - 1)])
    }

    /// Cast one ray per pixel and call `f(pixel index, ray direction, hit)`.
    fn cast<F: FnMut(usize, &[f64; 3], &RayHit)>(
        &self,
        pose: &Matrix4<f64>,
        k: &Intrinsics,
        mut f: F,
    ) {
        let r = [0, 1, 2].map(|i| [0, 1, 2].map(|j| pose[(i, j)]));
        let eye = [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]];
        let rects: Vec<Option<[i64; 4]>> = self
            .prims
            .iter()
            .map(|p| Self::rect(&r, &eye, k, p))
            .collect();
        let mut cands: Vec<(usize, i64, i64)> = Vec::with_capacity(self.prims.len());
        for v in 0..k.height as i64 {
            cands.clear();
            for (i, rc) in rects.iter().enumerate() {
                if let Some(rc) = rc {
                    if v >= rc[2] && v <= rc[3] {
                        cands.push((i, rc[0], rc[1]));
                    }
                }
            }
            for u in 0..k.width as i64 {
                let (a, b) = ((u as f64 - k.cx) / k.fx, (v as f64 - k.cy) / k.fy);
                let dir = [0, 1, 2].map(|i| r[i][0] * a + r[i][1] * b + r[i][2]);
                let mut best = self.shell(&eye, &dir);
                for &(pi, u0, u1) in &cands {
                    if u < u0 || u > u1 {
                        continue;
                    }
                    if let Some(h) = self.prims[pi].shape.intersect(eye, dir) {
                        if h.t < best.t {
                            best = RayHit {
                                t: h.t,
                                n: h.n,
                                prim: Some(pi),
                            };
                        }
                    }
                }
                f((v * k.width as i64 + u) as usize, &dir, &best);
            }
        }
    }

    /// Where the ray leaves the room's box (floor, walls, ceiling).
    fn shell(&self, o: &[f64; 3], d: &[f64; 3]) -> RayHit {
        let mut best = RayHit {
            t: f64::INFINITY,
            n: [0.0, 0.0, 1.0],
            prim: None,
        };
        for a in 0..3 {
            let (t, s) = if d[a] > 0.0 {
                ((self.room[a] - o[a]) / d[a], -1.0)
            } else if d[a] < 0.0 {
                (-o[a] / d[a], 1.0)
            } else {
                continue;
            };
            if t < best.t {
                let mut n = [0.0; 3];
                n[a] = s;
                best = RayHit { t, n, prim: None };
            }
        }
        best
    }

    /// Colour image and instance mask at `k`'s size.
    pub fn render_color(&self, pose: &Matrix4<f64>, k: &Intrinsics) -> ColorFrame {
        let n = k.width as usize * k.height as usize;
        let mut rgb = vec![0u8; n * 3];
        let mut instance = vec![0u16; n];
        let eye = [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]];
        let gamma: Vec<u8> = (0..GAMMA_LUT)
            .map(|i| ((i as f64 / (GAMMA_LUT - 1) as f64).powf(1.0 / 2.2) * 255.0 + 0.5) as u8)
            .collect();
        self.cast(pose, k, |i, dir, hit| {
            let p = [0, 1, 2].map(|c| eye[c] + dir[c] * hit.t);
            let base = match hit.prim {
                Some(pi) => {
                    let pr = &self.prims[pi];
                    instance[i] = self.ids[pr.obj];
                    let tex = 0.65 * noise3(p, 12.0, self.seed + pr.obj as u64)
                        + 0.35 * noise3(p, 55.0, self.seed + 991);
                    pr.albedo.map(|c| c * (0.84 + 0.32 * tex))
                }
                None => self.shell_albedo(&p, &hit.n),
            };
            let mut light = 0.3;
            for l in &self.lights {
                let v = [l[0] - p[0], l[1] - p[1], l[2] - p[2]];
                let d2 = v[0] * v[0] + v[1] * v[1] + v[2] * v[2];
                let lam =
                    (hit.n[0] * v[0] + hit.n[1] * v[1] + hit.n[2] * v[2]).max(0.0) / d2.sqrt();
                light += 0.9 * lam / (1.0 + 0.15 * d2);
            }
            for c in 0..3 {
                let lin = (base[c] * light).clamp(0.0, 1.0);
                rgb[i * 3 + c] = gamma[(lin * (GAMMA_LUT - 1) as f64 + 0.5) as usize];
            }
        });
        ColorFrame { rgb, instance }
    }

    /// Depth in millimetres (exact, before any noise) at `k`'s size.
    pub fn render_depth(&self, pose: &Matrix4<f64>, k: &Intrinsics) -> DepthFrame {
        let n = k.width as usize * k.height as usize;
        let mut mm = vec![0u16; n];
        let mut cos = vec![0f32; n];
        self.cast(pose, k, |i, dir, hit| {
            mm[i] = (hit.t * 1000.0).round().clamp(0.0, 65535.0) as u16;
            let len = (dir[0] * dir[0] + dir[1] * dir[1] + dir[2] * dir[2]).sqrt();
            let dot = dir[0] * hit.n[0] + dir[1] * hit.n[1] + dir[2] * hit.n[2];
            cos[i] = (dot.abs() / len) as f32;
        });
        DepthFrame {
            width: k.width,
            height: k.height,
            mm,
            cos,
        }
    }

    fn shell_albedo(&self, p: &[f64; 3], n: &[f64; 3]) -> [f64; 3] {
        if n[2] > 0.5 {
            // Floor.
            let tone = if self.tiles {
                let (a, b) = ((p[0] / 0.45).floor() as i64, (p[1] / 0.45).floor() as i64);
                let grout = (p[0] / 0.45).fract() < 0.02 || (p[1] / 0.45).fract() < 0.02;
                if grout {
                    0.55
                } else {
                    0.9 + 0.2 * hash(a, b, 3, self.seed)
                }
            } else {
                let plank = (p[1] / 0.14).floor() as i64;
                0.8 + 0.4
                    * hash(plank, 0, 4, self.seed)
                    * (0.8 + 0.2 * noise3(*p, 30.0, self.seed + 5))
            };
            self.floor.map(|c| c * tone)
        } else if n[2] < -0.5 {
            [0.8, 0.8, 0.78]
        } else {
            let m = 0.94 + 0.1 * noise3(*p, 4.0, self.seed + 9);
            self.wall.map(|c| c * m)
        }
    }
}

/// Trilinear value noise in [0, 1] at frequency `f` (cycles per metre).
fn noise3(p: [f64; 3], f: f64, seed: u64) -> f64 {
    let q = p.map(|x| x * f);
    let fl = q.map(f64::floor);
    let t = [0, 1, 2].map(|i| {
        let x = q[i] - fl[i];
        x * x * (3.0 - 2.0 * x)
    });
    let (ix, iy, iz) = (fl[0] as i64, fl[1] as i64, fl[2] as i64);
    let mut acc = 0.0;
    for c in 0..8 {
        let (dx, dy, dz) = (c & 1, (c >> 1) & 1, (c >> 2) & 1);
        let wgt = (if dx == 1 { t[0] } else { 1.0 - t[0] })
            * (if dy == 1 { t[1] } else { 1.0 - t[1] })
            * (if dz == 1 { t[2] } else { 1.0 - t[2] });
        acc += wgt * hash(ix + dx, iy + dy, iz + dz, seed);
    }
    acc
}

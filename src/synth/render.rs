//! Ray caster for box worlds: colour (Lambert shading + procedural texture), depth and
//! instance ids. Rays go through integer pixel coordinates (u, v) of the given intrinsics,
//! which keeps colour and depth consistent with the FORMATS §1 size-ratio lookup when the
//! depth intrinsics are the colour ones scaled to the depth size.

use super::room::World;
use super::SynthParams;
use crate::geometry::Intrinsics;
use nalgebra::Matrix4;

/// Entries of the linear -> sRGB-ish (gamma 2.2) lookup table.
const GAMMA_LUT: usize = 4096;

struct RBox {
    min: [f64; 3],
    max: [f64; 3],
    /// Index into the object list.
    obj: usize,
}

/// Immutable scene description shared by all frame renders.
pub(crate) struct Renderer {
    boxes: Vec<RBox>,
    ids: Vec<u16>,
    albedo: Vec<[f64; 3]>,
    room: [f64; 3],
    light: [f64; 3],
}

/// A rendered colour frame.
pub(crate) struct ColorFrame {
    /// Interleaved 8-bit RGB, row-major.
    pub rgb: Vec<u8>,
    /// Instance id per colour pixel (0 = floor, walls, ceiling).
    pub instance: Vec<u16>,
}

/// A rendered depth frame.
pub(crate) struct DepthFrame {
    pub width: u32,
    pub height: u32,
    /// Millimetres, 0 = no reading.
    pub mm: Vec<u16>,
    /// |cos| of the angle between the ray and the surface normal.
    pub cos: Vec<f32>,
}

#[derive(Clone, Copy)]
struct Hit {
    /// Camera-space z of the hit.
    t: f64,
    axis: usize,
    /// Sign of the outward normal along `axis`.
    sign: f64,
    /// Object index, or None for the room shell.
    obj: Option<usize>,
}

/// Per-frame camera: rotation columns, eye, and per-box screen rectangles.
struct View {
    r: [[f64; 3]; 3],
    eye: [f64; 3],
    k: Intrinsics,
    rects: Vec<Option<[i64; 4]>>,
}

impl View {
    fn new(pose: &Matrix4<f64>, k: &Intrinsics, boxes: &[RBox]) -> Self {
        let r = [0, 1, 2].map(|i| [0, 1, 2].map(|j| pose[(i, j)]));
        let eye = [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]];
        let mut v = View {
            r,
            eye,
            k: *k,
            rects: Vec::with_capacity(boxes.len()),
        };
        v.rects = boxes.iter().map(|b| v.rect(b)).collect();
        v
    }

    /// Ray direction (world) for pixel (u, v), scaled so its camera-z component is 1.
    #[inline]
    fn dir(&self, u: f64, v: f64) -> [f64; 3] {
        let (a, b) = ((u - self.k.cx) / self.k.fx, (v - self.k.cy) / self.k.fy);
        let r = &self.r;
        [
            r[0][0] * a + r[0][1] * b + r[0][2],
            r[1][0] * a + r[1][1] * b + r[1][2],
            r[2][0] * a + r[2][1] * b + r[2][2],
        ]
    }

    /// Conservative pixel rectangle [u0, u1, v0, v1] covered by the box; None when off-screen.
    fn rect(&self, b: &RBox) -> Option<[i64; 4]> {
        let (w, h) = (self.k.width as i64, self.k.height as i64);
        let mut lo = [f64::INFINITY; 2];
        let mut hi = [f64::NEG_INFINITY; 2];
        for c in 0..8 {
            let p = [
                if c & 1 == 0 { b.min[0] } else { b.max[0] },
                if c & 2 == 0 { b.min[1] } else { b.max[1] },
                if c & 4 == 0 { b.min[2] } else { b.max[2] },
            ];
            let d = [p[0] - self.eye[0], p[1] - self.eye[1], p[2] - self.eye[2]];
            let cam =
                [0, 1, 2].map(|j| self.r[0][j] * d[0] + self.r[1][j] * d[1] + self.r[2][j] * d[2]);
            if cam[2] < 0.02 {
                return Some([0, w - 1, 0, h - 1]);
            }
            let u = self.k.fx * cam[0] / cam[2] + self.k.cx;
            let v = self.k.fy * cam[1] / cam[2] + self.k.cy;
            lo = [lo[0].min(u), lo[1].min(v)];
            hi = [hi[0].max(u), hi[1].max(v)];
        }
        let r = [
            lo[0].floor() as i64 - 1,
            hi[0].ceil() as i64 + 1,
            lo[1].floor() as i64 - 1,
            hi[1].ceil() as i64 + 1,
        ];
        if r[1] < 0 || r[0] >= w || r[3] < 0 || r[2] >= h {
            return None;
        }
        Some([r[0].max(0), r[1].min(w - 1), r[2].max(0), r[3].min(h - 1)])
    }
}

impl Renderer {
    pub fn new(world: &World) -> Self {
        let mut boxes = Vec::new();
        for (i, o) in world.objects.iter().enumerate() {
            for p in &o.parts {
                boxes.push(RBox {
                    min: p.min,
                    max: p.max,
                    obj: i,
                });
            }
        }
        let (w, d, h) = world.size;
        Renderer {
            boxes,
            ids: world.objects.iter().map(|o| o.id as u16).collect(),
            albedo: world.objects.iter().map(|o| o.rgb).collect(),
            room: [w, d, h],
            light: [w * 0.45, d * 0.55, h - 0.25],
        }
    }

    /// Nearest hit along `dir` from the eye among the candidate boxes (room shell always).
    #[inline]
    fn trace(&self, view: &View, dir: &[f64; 3], cands: &[(usize, i64, i64)], u: i64) -> Hit {
        let o = &view.eye;
        let inv = [1.0 / dir[0], 1.0 / dir[1], 1.0 / dir[2]];
        // Room shell: the ray leaves the room's interior.
        let mut best = Hit {
            t: f64::INFINITY,
            axis: 2,
            sign: 1.0,
            obj: None,
        };
        for a in 0..3 {
            let t = if dir[a] > 0.0 {
                (self.room[a] - o[a]) * inv[a]
            } else if dir[a] < 0.0 {
                -o[a] * inv[a]
            } else {
                f64::INFINITY
            };
            if t < best.t {
                best = Hit {
                    t,
                    axis: a,
                    sign: if dir[a] > 0.0 { -1.0 } else { 1.0 },
                    obj: None,
                };
            }
        }
        for &(bi, u0, u1) in cands {
            if u < u0 || u > u1 {
                continue;
            }
            let b = &self.boxes[bi];
            // Slab test, written out: this is the hot loop (also in debug builds).
            let (n0, f0) = slab(b.min[0], b.max[0], o[0], inv[0]);
            let (n1, f1) = slab(b.min[1], b.max[1], o[1], inv[1]);
            let (n2, f2) = slab(b.min[2], b.max[2], o[2], inv[2]);
            let (mut tmin, mut axis) = (n0, 0);
            if n1 > tmin {
                tmin = n1;
                axis = 1;
            }
            if n2 > tmin {
                tmin = n2;
                axis = 2;
            }
            let mut tmax = f0;
            if f1 < tmax {
                tmax = f1;
            }
            if f2 < tmax {
                tmax = f2;
            }
            if tmax >= tmin && tmin > 1e-6 && tmin < best.t {
                best = Hit {
                    t: tmin,
                    axis,
                    sign: if dir[axis] > 0.0 { -1.0 } else { 1.0 },
                    obj: Some(b.obj),
                };
            }
        }
        best
    }

    /// Render every pixel of `k`'s image with `f(u, v, dir, hit)`.
    fn cast<F: FnMut(usize, &[f64; 3], &Hit)>(
        &self,
        pose: &Matrix4<f64>,
        k: &Intrinsics,
        mut f: F,
    ) {
        let view = View::new(pose, k, &self.boxes);
        let mut cands = Vec::with_capacity(self.boxes.len());
        for v in 0..k.height as i64 {
            cands.clear();
            for (i, r) in view.rects.iter().enumerate() {
                if let Some(r) = r {
                    if v >= r[2] && v <= r[3] {
                        cands.push((i, r[0], r[1]));
                    }
                }
            }
            for u in 0..k.width as i64 {
                let dir = view.dir(u as f64, v as f64);
                let hit = self.trace(&view, &dir, &cands, u);
                f((v * k.width as i64 + u) as usize, &dir, &hit);
            }
        }
    }

    /// Colour image and instance mask at `k`'s size.
    pub fn render_color(
        &self,
        pose: &Matrix4<f64>,
        k: &Intrinsics,
        params: &SynthParams,
        _frame: usize,
    ) -> ColorFrame {
        let n = k.width as usize * k.height as usize;
        let mut rgb = vec![0u8; n * 3];
        let mut instance = vec![0u16; n];
        let eye = [pose[(0, 3)], pose[(1, 3)], pose[(2, 3)]];
        let seed = params.seed;
        let gamma: Vec<u8> = (0..GAMMA_LUT)
            .map(|i| ((i as f64 / (GAMMA_LUT - 1) as f64).powf(1.0 / 2.2) * 255.0 + 0.5) as u8)
            .collect();
        self.cast(pose, k, |i, dir, hit| {
            let p = [
                eye[0] + dir[0] * hit.t,
                eye[1] + dir[1] * hit.t,
                eye[2] + dir[2] * hit.t,
            ];
            let mut nrm = [0.0; 3];
            nrm[hit.axis] = hit.sign;
            let albedo = match hit.obj {
                Some(o) => {
                    instance[i] = self.ids[o];
                    let (a, b) = face_coords(&p, hit.axis);
                    let tex = value_noise2(a * 9.0, b * 9.0, seed + o as u64) * 0.6
                        + value_noise2(a * 40.0, b * 40.0, seed + 77) * 0.4;
                    let m = 0.82 + 0.36 * tex;
                    let c = &self.albedo[o];
                    [c[0] * m, c[1] * m, c[2] * m]
                }
                None => self.room_albedo(&p, hit.axis, hit.sign, seed),
            };
            let l = [
                self.light[0] - p[0],
                self.light[1] - p[1],
                self.light[2] - p[2],
            ];
            let dist2 = l[0] * l[0] + l[1] * l[1] + l[2] * l[2];
            let lambert = (nrm[0] * l[0] + nrm[1] * l[1] + nrm[2] * l[2]).max(0.0) / dist2.sqrt();
            let shade = 0.28 + 1.5 * lambert / (1.0 + 0.12 * dist2);
            for c in 0..3 {
                let lin = (albedo[c] * shade).clamp(0.0, 1.0);
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
            cos[i] = (dir[hit.axis].abs() / len) as f32;
        });
        DepthFrame {
            width: k.width,
            height: k.height,
            mm,
            cos,
        }
    }

    fn room_albedo(&self, p: &[f64; 3], axis: usize, sign: f64, seed: u64) -> [f64; 3] {
        if axis == 2 && sign > 0.0 {
            // Floor: wooden planks 18 cm wide with grain.
            let plank = (p[0] / 0.18).floor();
            let offset = hash(plank as i64, 0, 0, seed + 5) * 1.3;
            let board = ((p[1] + offset) / 1.3).floor();
            let tone = 0.8 + 0.4 * hash(plank as i64, board as i64, 1, seed + 6);
            let grain = value_noise2(p[0] * 60.0, p[1] * 4.0, seed + 7);
            [0.32, 0.19, 0.09].map(|c| c * tone * (0.85 + 0.3 * grain))
        } else if axis == 2 {
            [0.75, 0.75, 0.73]
        } else {
            let (a, b) = face_coords(p, axis);
            let n = value_noise2(a * 3.0, b * 3.0, seed + 9);
            [0.62, 0.60, 0.55].map(|c| c * (0.93 + 0.12 * n))
        }
    }
}

/// Entry and exit ray parameters of one slab.
#[inline(always)]
fn slab(lo: f64, hi: f64, o: f64, inv: f64) -> (f64, f64) {
    let t0 = (lo - o) * inv;
    let t1 = (hi - o) * inv;
    if t0 < t1 {
        (t0, t1)
    } else {
        (t1, t0)
    }
}

/// Deterministic 64-bit hash of an integer lattice point (splitmix64 finaliser).
#[inline]
pub(crate) fn hash_u64(x: i64, y: i64, z: i64, seed: u64) -> u64 {
    let mut h = seed.wrapping_mul(0x9E37_79B9_7F4A_7C15)
        ^ (x as u64).wrapping_mul(0xBF58_476D_1CE4_E5B9)
        ^ (y as u64).wrapping_mul(0x94D0_49BB_1331_11EB)
        ^ (z as u64).wrapping_mul(0xD6E8_FEB8_6659_FD93);
    h ^= h >> 30;
    h = h.wrapping_mul(0xBF58_476D_1CE4_E5B9);
    h ^= h >> 27;
    h = h.wrapping_mul(0x94D0_49BB_1331_11EB);
    h ^ (h >> 31)
}

/// Deterministic hash of an integer lattice point to [0, 1).
#[inline]
pub(crate) fn hash(x: i64, y: i64, z: i64, seed: u64) -> f64 {
    (hash_u64(x, y, z, seed) >> 11) as f64 / (1u64 << 53) as f64
}

/// The two in-plane coordinates of a point on a face perpendicular to `axis`.
#[inline]
fn face_coords(p: &[f64; 3], axis: usize) -> (f64, f64) {
    match axis {
        0 => (p[1], p[2]),
        1 => (p[0], p[2]),
        _ => (p[0], p[1]),
    }
}

/// Bilinear value noise in [0, 1] (smoothstep-interpolated hashed lattice).
fn value_noise2(x: f64, y: f64, seed: u64) -> f64 {
    let (fx, fy) = (x.floor(), y.floor());
    let (tx, ty) = (x - fx, y - fy);
    let (tx, ty) = (tx * tx * (3.0 - 2.0 * tx), ty * ty * (3.0 - 2.0 * ty));
    let (ix, iy) = (fx as i64, fy as i64);
    let a = hash(ix, iy, 0, seed);
    let b = hash(ix + 1, iy, 0, seed);
    let c = hash(ix, iy + 1, 0, seed);
    let d = hash(ix + 1, iy + 1, 0, seed);
    let top = a + (b - a) * tx;
    let bot = c + (d - c) * tx;
    top + (bot - top) * ty
}

//! Small synthetic RGB-D scene for geometry tests and benchmarks: a room with a few
//! oriented boxes, ray-cast into colour-resolution instance masks and lower-resolution
//! depth maps with realistic sensor faults (noise growing with distance, mm quantisation,
//! holes, dropped grazing surfaces, flying pixels at depth edges) and jittered poses.
//! Shared by tests/suite/geometry_synthetic.rs and benches/geometry.rs (`#[path]` include).
#![allow(dead_code)]

use grounder::geometry::camera::look_at_pose;
use grounder::geometry::{Aabb, DepthMap, FrameCamera, Intrinsics, Mask};
use nalgebra::{Matrix4, Point3, Rotation3, Translation3, Vector3};
use rand::{Rng, SeedableRng};
use rand_chacha::ChaCha8Rng;

/// An object: box with centre, half extents and yaw about the vertical axis (aligned frame).
#[derive(Debug, Clone, Copy)]
pub struct Object {
    pub id: u16,
    pub center: Point3<f64>,
    pub half: Vector3<f64>,
    pub yaw: f64,
}

impl Object {
    fn rot(&self) -> Rotation3<f64> {
        Rotation3::from_axis_angle(&Vector3::z_axis(), self.yaw)
    }

    /// Ground-truth axis-aligned box (of the object's corners = of its surface points).
    pub fn gt_box(&self) -> Aabb {
        let r = self.rot();
        let corners: Vec<Point3<f64>> = (0..8)
            .map(|i| {
                let s = Vector3::new(
                    if i & 1 == 0 { -1.0 } else { 1.0 },
                    if i & 2 == 0 { -1.0 } else { 1.0 },
                    if i & 4 == 0 { -1.0 } else { 1.0 },
                );
                self.center + r * self.half.component_mul(&s)
            })
            .collect();
        Aabb::from_points(&corners).unwrap_or(Aabb::new([0.0; 3], [0.0; 3]))
    }

    /// Largest side (m).
    pub fn max_extent(&self) -> f64 {
        2.0 * self.half.max()
    }
}

/// One rendered view.
pub struct View {
    pub camera: FrameCamera,
    pub depth: DepthMap,
    /// Instance id per colour pixel (0 = room).
    pub instance: Vec<u16>,
}

impl View {
    /// Ground-truth colour-resolution mask of one object.
    pub fn mask_of(&self, id: u16) -> Mask {
        let c = &self.camera.color;
        Mask {
            width: c.width,
            height: c.height,
            data: self.instance.iter().map(|&i| i == id).collect(),
        }
    }

    /// Most frequent non-zero instance id among the given colour pixels.
    pub fn majority_id(&self, pixels: &[[u32; 2]]) -> Option<u16> {
        let mut counts = std::collections::HashMap::new();
        for &[x, y] in pixels {
            let id = self.instance[(y * self.camera.color.width + x) as usize];
            if id != 0 {
                *counts.entry(id).or_insert(0usize) += 1;
            }
        }
        counts
            .into_iter()
            .max_by_key(|&(id, n)| (n, std::cmp::Reverse(id)))
            .map(|(id, _)| id)
    }
}

pub struct Scene {
    pub objects: Vec<Object>,
    pub views: Vec<View>,
}

const ROOM: ([f64; 3], [f64; 3]) = ([-3.0, -3.0, 0.0], [3.0, 3.0, 2.6]);

fn room_hit(o: &Point3<f64>, d: &Vector3<f64>) -> (f64, f64) {
    let (mut t, mut axis) = (f64::INFINITY, 2);
    for i in 0..3 {
        if d[i].abs() < 1e-12 {
            continue;
        }
        let b = if d[i] > 0.0 { ROOM.1[i] } else { ROOM.0[i] };
        let ti = (b - o[i]) / d[i];
        if ti > 0.0 && ti < t {
            t = ti;
            axis = i;
        }
    }
    (t, d[axis].abs() / d.norm())
}

/// Object prepared for fast ray casting in plain f64 (tests run unoptimised).
#[derive(Clone, Copy)]
struct Caster {
    id: u16,
    c: [f64; 3],
    half: [f64; 3],
    rinv: [[f64; 3]; 3],
}

impl Caster {
    fn new(o: &Object) -> Self {
        let m = o.rot().inverse().into_inner();
        let rinv = [0, 1, 2].map(|r| [m[(r, 0)], m[(r, 1)], m[(r, 2)]]);
        Self {
            id: o.id,
            c: [o.center.x, o.center.y, o.center.z],
            half: [o.half.x, o.half.y, o.half.z],
            rinv,
        }
    }

    fn hit(&self, o: &[f64; 3], d: &[f64; 3]) -> Option<(f64, f64)> {
        let rel = [o[0] - self.c[0], o[1] - self.c[1], o[2] - self.c[2]];
        let mul = |v: &[f64; 3]| self.rinv.map(|r| r[0] * v[0] + r[1] * v[1] + r[2] * v[2]);
        let (lo, ld) = (mul(&rel), mul(d));
        let (mut t0, mut t1, mut axis) = (f64::NEG_INFINITY, f64::INFINITY, 0);
        for i in 0..3 {
            if ld[i].abs() < 1e-12 {
                if lo[i].abs() > self.half[i] {
                    return None;
                }
                continue;
            }
            let a = (-self.half[i] - lo[i]) / ld[i];
            let b = (self.half[i] - lo[i]) / ld[i];
            let (a, b) = if a < b { (a, b) } else { (b, a) };
            if a > t0 {
                t0 = a;
                axis = i;
            }
            t1 = t1.min(b);
        }
        let n = (ld[0] * ld[0] + ld[1] * ld[1] + ld[2] * ld[2]).sqrt();
        (t0 <= t1 && t0 > 1e-6).then(|| (t0, ld[axis].abs() / n))
    }
}

/// Per-view ray caster: camera centre, rotation and each object's 2D pixel bounds.
struct ViewCaster<'a> {
    o: [f64; 3],
    r: [[f64; 3]; 3],
    k: Intrinsics,
    objects: Vec<(&'a Caster, [f64; 4])>,
}

impl<'a> ViewCaster<'a> {
    fn new(casters: &'a [(Object, Caster)], k: &Intrinsics, pose_a: &Matrix4<f64>) -> Self {
        let inv = pose_a.try_inverse().unwrap_or_else(Matrix4::identity);
        let objects = casters
            .iter()
            .map(|(ob, c)| {
                let b = ob.gt_box();
                let mut bb = [
                    f64::INFINITY,
                    f64::INFINITY,
                    f64::NEG_INFINITY,
                    f64::NEG_INFINITY,
                ];
                for i in 0..8 {
                    let p = Point3::new(
                        if i & 1 == 0 { b.min[0] } else { b.max[0] },
                        if i & 2 == 0 { b.min[1] } else { b.max[1] },
                        if i & 4 == 0 { b.min[2] } else { b.max[2] },
                    );
                    let pc = inv.transform_point(&p);
                    if pc.z < 0.05 {
                        bb = [
                            f64::NEG_INFINITY,
                            f64::NEG_INFINITY,
                            f64::INFINITY,
                            f64::INFINITY,
                        ];
                        break;
                    }
                    let (u, v) = (k.fx * pc.x / pc.z + k.cx, k.fy * pc.y / pc.z + k.cy);
                    bb = [
                        bb[0].min(u - 1.0),
                        bb[1].min(v - 1.0),
                        bb[2].max(u + 1.0),
                        bb[3].max(v + 1.0),
                    ];
                }
                (c, bb)
            })
            .collect();
        Self {
            o: [pose_a[(0, 3)], pose_a[(1, 3)], pose_a[(2, 3)]],
            r: [0, 1, 2].map(|i| [pose_a[(i, 0)], pose_a[(i, 1)], pose_a[(i, 2)]]),
            k: *k,
            objects,
        }
    }

    /// (t along the un-normalised camera ray = camera depth z, |cos| to normal, instance id).
    fn cast(&self, x: u32, y: u32) -> (f64, f64, u16) {
        let (u, v) = (x as f64, y as f64);
        let dc = [
            (u - self.k.cx) / self.k.fx,
            (v - self.k.cy) / self.k.fy,
            1.0,
        ];
        let d = self.r.map(|r| r[0] * dc[0] + r[1] * dc[1] + r[2] * dc[2]);
        let (mut t, mut cos) = room_hit(&Point3::from(self.o), &Vector3::from(d));
        let mut id = 0;
        for (c, bb) in &self.objects {
            if u < bb[0] || v < bb[1] || u > bb[2] || v > bb[3] {
                continue;
            }
            if let Some((ti, ci)) = c.hit(&self.o, &d) {
                if ti < t {
                    (t, cos, id) = (ti, ci, c.id);
                }
            }
        }
        (t, cos, id)
    }
}

fn gauss(rng: &mut ChaCha8Rng) -> f64 {
    let (u1, u2): (f64, f64) = (rng.gen_range(1e-12..1.0), rng.gen());
    (-2.0 * u1.ln()).sqrt() * (std::f64::consts::TAU * u2).cos()
}

/// Render the depth map of a camera with true pose `pose_a` (aligned frame), with noise.
fn render_depth(
    casters: &[(Object, Caster)],
    k: &Intrinsics,
    pose_a: &Matrix4<f64>,
    rng: &mut ChaCha8Rng,
) -> DepthMap {
    let (w, h) = (k.width as usize, k.height as usize);
    let vc = ViewCaster::new(casters, k, pose_a);
    let mut clean = vec![0.0f64; w * h];
    let mut cosv = vec![1.0f64; w * h];
    for y in 0..h {
        for x in 0..w {
            let (t, c, _) = vc.cast(x as u32, y as u32);
            clean[y * w + x] = t;
            cosv[y * w + x] = c;
        }
    }
    let mut data = vec![0u16; w * h];
    for y in 0..h {
        for x in 0..w {
            let i = y * w + x;
            let mut z = clean[i];
            // Flying pixels: at a depth edge, half of the pixels mix both surfaces.
            let mut far = z;
            for (dx, dy) in [(-1i64, 0i64), (1, 0), (0, -1), (0, 1)] {
                let (nx, ny) = (x as i64 + dx, y as i64 + dy);
                if nx >= 0 && ny >= 0 && (nx as usize) < w && (ny as usize) < h {
                    let zn = clean[ny as usize * w + nx as usize];
                    if (zn - z).abs() > (far - z).abs() {
                        far = zn;
                    }
                }
            }
            if (far - z).abs() > 0.15 && rng.gen_bool(0.5) {
                z += (far - z) * rng.gen_range(0.15..0.85);
            }
            // Axial noise of a structured-light sensor, growing with distance.
            let sigma = 0.0012 + 0.0019 * (z - 0.4) * (z - 0.4);
            z += sigma * gauss(rng);
            let hole = rng.gen_bool(0.03) || cosv[i] < 0.12 || z > 6.0;
            data[i] = if hole {
                0
            } else {
                (z * 1000.0).round().clamp(1.0, 65535.0) as u16
            };
        }
    }
    DepthMap::new(k.width, k.height, data)
}

fn render_instance(
    casters: &[(Object, Caster)],
    k: &Intrinsics,
    pose_a: &Matrix4<f64>,
) -> Vec<u16> {
    let vc = ViewCaster::new(casters, k, pose_a);
    let mut out = Vec::with_capacity((k.width * k.height) as usize);
    for y in 0..k.height {
        for x in 0..k.width {
            out.push(vc.cast(x, y).2);
        }
    }
    out
}

/// The default scene objects (ids 1..): furniture-sized boxes plus two small ones.
pub fn default_objects() -> Vec<Object> {
    let b = |id, c: [f64; 3], s: [f64; 3], yaw: f64| Object {
        id,
        center: Point3::new(c[0], c[1], c[2]),
        half: Vector3::new(s[0] / 2.0, s[1] / 2.0, s[2] / 2.0),
        yaw,
    };
    vec![
        b(1, [0.0, 0.0, 0.375], [1.2, 0.8, 0.75], 0.3), // table
        b(2, [0.1, 0.05, 0.875], [0.3, 0.25, 0.25], 0.9), // box on the table
        b(3, [-1.4, 1.2, 0.45], [0.5, 0.5, 0.9], -0.4), // chair-sized block
        b(4, [1.6, -1.3, 0.4], [1.8, 0.8, 0.8], 0.6),   // sofa
        b(5, [-2.5, -1.5, 0.6], [0.5, 1.0, 1.2], 0.0),  // cabinet near a wall
        b(6, [1.8, 1.6, 0.2], [0.35, 0.35, 0.4], 0.2),  // bin
        b(7, [-0.9, -1.2, 0.06], [0.12, 0.12, 0.12], 0.5), // small (not counted)
        b(8, [2.3, 0.2, 0.35], [0.4, 0.6, 0.7], -0.2),  // nightstand
        b(9, [-0.4, 1.9, 0.075], [0.15, 0.1, 0.15], 0.0), // small (not counted)
    ]
}

/// Axis-alignment used by the scene (world -> aligned): a yaw and an offset.
pub fn align_matrix() -> Matrix4<f64> {
    let r = Rotation3::from_axis_angle(&Vector3::z_axis(), 0.35);
    Translation3::new(0.4, -0.7, 0.0).to_homogeneous() * r.to_homogeneous()
}

/// Render `n_views` views (colour `cw` x `ch`, depth at 3/4 of that) around the room.
pub fn render_scene(seed: u64, cw: u32, ch: u32, n_views: usize) -> Scene {
    render_scene_sized(seed, (cw, ch), (cw * 3 / 4, ch * 3 / 4), n_views)
}

/// Render `n_views` views with explicit colour and depth image sizes.
pub fn render_scene_sized(
    seed: u64,
    (cw, ch): (u32, u32),
    (dw, dh): (u32, u32),
    n_views: usize,
) -> Scene {
    let mut rng = ChaCha8Rng::seed_from_u64(seed);
    let objects = default_objects();
    let casters: Vec<_> = objects.iter().map(|o| (*o, Caster::new(o))).collect();
    let color = Intrinsics {
        fx: 0.82 * cw as f64,
        fy: 0.82 * cw as f64,
        cx: (cw as f64 - 1.0) / 2.0,
        cy: (ch as f64 - 1.0) / 2.0,
        width: cw,
        height: ch,
    };
    let dk = color.scaled_to(dw, dh);
    let align = align_matrix();
    let align_inv = align.try_inverse().unwrap_or_else(Matrix4::identity);
    let mut views = Vec::new();
    for v in 0..n_views {
        let a = std::f64::consts::TAU * v as f64 / n_views as f64 + rng.gen_range(-0.1..0.1);
        let radius = if v % 3 == 2 { 1.6 } else { 2.6 };
        let eye = Point3::new(radius * a.cos(), radius * a.sin(), rng.gen_range(1.2..1.8));
        let target = Point3::new(
            rng.gen_range(-0.8..0.8),
            rng.gen_range(-0.8..0.8),
            rng.gen_range(0.2..0.6),
        );
        let pose_a = look_at_pose(eye, target, Vector3::z());
        let depth = render_depth(&casters, &dk, &pose_a, &mut rng);
        let instance = render_instance(&casters, &color, &pose_a);
        // Stored pose: world frame, with estimation error (~0.6 deg, ~1 cm).
        let axis = Vector3::new(gauss(&mut rng), gauss(&mut rng), gauss(&mut rng)).normalize();
        let jitter = Translation3::new(
            0.01 * gauss(&mut rng),
            0.01 * gauss(&mut rng),
            0.01 * gauss(&mut rng),
        )
        .to_homogeneous()
            * Rotation3::from_axis_angle(
                &nalgebra::Unit::new_normalize(axis),
                0.01 * gauss(&mut rng),
            )
            .to_homogeneous();
        let pose = align_inv * jitter * pose_a;
        let camera = FrameCamera {
            color,
            depth: None,
            depth_size: (dw, dh),
            pose,
            align,
        };
        views.push(View {
            camera,
            depth,
            instance,
        });
    }
    Scene { objects, views }
}

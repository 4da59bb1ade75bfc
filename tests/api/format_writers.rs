//! Writers that lay a synthetic scene out as each capture format, byte for byte as the
//! real tools do: ScanNet's `.sens` (SensorData v4), a TUM RGB-D folder, a nerfstudio
//! `transforms.json` export and an ARKitScenes raw `<video>_frames/` folder. Poses are the
//! synthetic frames' aligned poses, so boxes compare with the ScanNet-layout import.
//! Each writer also copies the scene's `instance/` masks (named by frame position) so the
//! oracle detector can index the import.

use grounder::synth::SynthScene;
use nalgebra::{Matrix4, Rotation3};
use std::io::Write;

pub type Files = Vec<(String, Vec<u8>)>;

fn read(scene: &SynthScene, rel: &str) -> Vec<u8> {
    std::fs::read(scene.dir.join(rel)).unwrap_or_else(|e| panic!("{rel}: {e}"))
}

fn depth_mm(scene: &SynthScene, name: &str) -> (u32, u32, Vec<u16>) {
    let img = image::open(scene.dir.join(format!("depth/{name}.png")))
        .expect("synth depth")
        .into_luma16();
    (img.width(), img.height(), img.into_raw())
}

fn png16(w: u32, h: u32, v: Vec<u16>) -> Vec<u8> {
    let img = image::ImageBuffer::<image::Luma<u16>, Vec<u16>>::from_raw(w, h, v).unwrap();
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .unwrap();
    out
}

fn png_rgb(jpeg: &[u8]) -> Vec<u8> {
    let img = image::load_from_memory(jpeg).unwrap().to_rgb8();
    let mut out = Vec::new();
    img.write_to(&mut std::io::Cursor::new(&mut out), image::ImageFormat::Png)
        .unwrap();
    out
}

/// Camera-to-world pose of frame `i` in the output (aligned) frame; inf when invalid.
pub fn pose(scene: &SynthScene, i: usize) -> Matrix4<f64> {
    let f = &scene.frames[i];
    if f.pose_valid {
        f.pose_aligned
    } else {
        Matrix4::from_element(f64::NEG_INFINITY)
    }
}

fn instances(scene: &SynthScene, prefix: &str) -> Files {
    let mut out = Vec::new();
    for (i, f) in scene.frames.iter().enumerate() {
        out.push((
            format!("{prefix}instance/{i}.png"),
            read(scene, &format!("instance/{}.png", f.name)),
        ));
    }
    out.push((
        format!("{prefix}instance/labels.json"),
        read(scene, "instance/labels.json"),
    ));
    out
}

fn k4(scene: &SynthScene, depth: bool) -> Matrix4<f64> {
    let k = if depth {
        scene.depth_intrinsics
    } else {
        scene.color_intrinsics
    };
    let mut m = Matrix4::identity();
    m[(0, 0)] = k.fx;
    m[(1, 1)] = k.fy;
    m[(0, 2)] = k.cx;
    m[(1, 2)] = k.cy;
    m
}

fn put_mat(out: &mut Vec<u8>, m: &Matrix4<f64>) {
    for r in 0..4 {
        for c in 0..4 {
            out.extend_from_slice(&(m[(r, c)] as f32).to_le_bytes());
        }
    }
}

/// ScanNet `.sens` (SensorData version 4, JPEG colour, zlib depth).
pub fn sens(scene: &SynthScene) -> Vec<u8> {
    let mut out = sens_header(scene, scene.frames.len() as u64);
    for i in 0..scene.frames.len() {
        out.extend(sens_frame(scene, i));
    }
    out.extend_from_slice(&0u64.to_le_bytes()); // no IMU frames
    out
}

/// The `.sens` header announcing `frames` frames.
pub fn sens_header(scene: &SynthScene, frames: u64) -> Vec<u8> {
    let mut out = Vec::new();
    out.extend_from_slice(&4u32.to_le_bytes());
    let sensor = b"StructureSensor";
    out.extend_from_slice(&(sensor.len() as u64).to_le_bytes());
    out.extend_from_slice(sensor);
    put_mat(&mut out, &k4(scene, false));
    put_mat(&mut out, &Matrix4::identity());
    put_mat(&mut out, &k4(scene, true));
    put_mat(&mut out, &Matrix4::identity());
    out.extend_from_slice(&2i32.to_le_bytes()); // JPEG
    out.extend_from_slice(&1i32.to_le_bytes()); // zlib u16
    let (cw, ch) = scene.params.color_size;
    let (dw, dh) = scene.params.depth_size;
    for v in [cw, ch, dw, dh] {
        out.extend_from_slice(&v.to_le_bytes());
    }
    out.extend_from_slice(&1000f32.to_le_bytes());
    out.extend_from_slice(&frames.to_le_bytes());
    out
}

/// One `.sens` frame record (pose, timestamps, sizes, JPEG, zlib depth) of frame `i`.
pub fn sens_frame(scene: &SynthScene, i: usize) -> Vec<u8> {
    let mut out = Vec::new();
    let f = &scene.frames[i];
    put_mat(&mut out, &pose(scene, i));
    out.extend_from_slice(&(i as u64 * 33_333).to_le_bytes());
    out.extend_from_slice(&(i as u64 * 33_333).to_le_bytes());
    let jpg = read(scene, &format!("color/{}.jpg", f.name));
    let (_, _, mm) = depth_mm(scene, &f.name);
    let raw: Vec<u8> = mm.iter().flat_map(|v| v.to_le_bytes()).collect();
    let mut z = flate2::write::ZlibEncoder::new(Vec::new(), flate2::Compression::default());
    z.write_all(&raw).unwrap();
    let zd = z.finish().unwrap();
    out.extend_from_slice(&(jpg.len() as u64).to_le_bytes());
    out.extend_from_slice(&(zd.len() as u64).to_le_bytes());
    out.extend_from_slice(&jpg);
    out.extend_from_slice(&zd);
    out
}

/// Frame times of the TUM / ARKitScenes writers (30 Hz from an arbitrary epoch).
pub fn frame_time(i: usize) -> f64 {
    1305031102.175304 + i as f64 / 30.0
}

/// A TUM RGB-D folder (PNG colour, depth at 5000 units per metre, groundtruth at 100 Hz
/// around the frames).
pub fn tum(scene: &SynthScene) -> Files {
    let mut files = Vec::new();
    let head =
        |what: &str| format!("# {what}\n# file: 'rgbd_dataset_synth.bag'\n# timestamp filename\n");
    let (mut rgb, mut depth) = (head("color images"), head("depth maps"));
    let mut gt = String::from(
        "# ground truth trajectory\n# file: 'rgbd_dataset_synth.bag'\n# timestamp tx ty tz qx qy qz qw\n",
    );
    for (i, f) in scene.frames.iter().enumerate() {
        let t = frame_time(i);
        let td = t + 0.004; // depth arrives a few ms later, as with a Kinect
        rgb.push_str(&format!("{t:.6} rgb/{t:.6}.png\n"));
        depth.push_str(&format!("{td:.6} depth/{td:.6}.png\n"));
        files.push((
            format!("rgb/{t:.6}.png"),
            png_rgb(&read(scene, &format!("color/{}.jpg", f.name))),
        ));
        let (w, h, mm) = depth_mm(scene, &f.name);
        files.push((
            format!("depth/{td:.6}.png"),
            png16(w, h, mm.iter().map(|v| v * 5).collect()),
        ));
        let p = pose(scene, i);
        let q = nalgebra::UnitQuaternion::from_matrix(&p.fixed_view::<3, 3>(0, 0).into_owned());
        // The same pose just before and after the frame: interpolation returns it.
        for dt in [-0.005, 0.005] {
            gt.push_str(&format!(
                "{:.4} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9} {:.9}\n",
                t + dt,
                p[(0, 3)],
                p[(1, 3)],
                p[(2, 3)],
                q.i,
                q.j,
                q.k,
                q.w
            ));
        }
    }
    let k = scene.color_intrinsics;
    files.push(("rgb.txt".into(), rgb.into_bytes()));
    files.push(("depth.txt".into(), depth.into_bytes()));
    files.push(("groundtruth.txt".into(), gt.into_bytes()));
    files.push((
        "intrinsics.txt".into(),
        format!("{} {} {} {}\n", k.fx, k.fy, k.cx, k.cy).into_bytes(),
    ));
    files.extend(instances(scene, ""));
    files
}

/// A nerfstudio export: `transforms.json` (OpenGL camera axes), `images/`, `depth/` (mm).
pub fn nerfstudio(scene: &SynthScene) -> (serde_json::Value, Files) {
    let mut files = Vec::new();
    let mut frames = Vec::new();
    for (i, f) in scene.frames.iter().enumerate() {
        let img = format!("images/frame_{:05}.jpg", i + 1);
        let dep = format!("depth/frame_{:05}.png", i + 1);
        files.push((img.clone(), read(scene, &format!("color/{}.jpg", f.name))));
        let (w, h, mm) = depth_mm(scene, &f.name);
        files.push((dep.clone(), png16(w, h, mm)));
        let mut gl = pose(scene, i);
        for r in 0..4 {
            gl[(r, 1)] = -gl[(r, 1)];
            gl[(r, 2)] = -gl[(r, 2)];
        }
        let rows: Vec<Vec<f64>> = (0..4)
            .map(|r| (0..4).map(|c| gl[(r, c)]).collect())
            .collect();
        frames.push(serde_json::json!({
            "file_path": img, "depth_file_path": dep, "transform_matrix": rows,
        }));
    }
    let k = scene.color_intrinsics;
    let t = serde_json::json!({
        "camera_model": "OPENCV", "fl_x": k.fx, "fl_y": k.fy, "cx": k.cx, "cy": k.cy,
        "w": k.width, "h": k.height, "k1": 0.0, "k2": 0.0, "p1": 0.0, "p2": 0.0,
        "frames": frames,
    });
    files.extend(instances(scene, ""));
    (t, files)
}

pub fn nerfstudio_files(scene: &SynthScene) -> Files {
    let (t, mut files) = nerfstudio(scene);
    files.push((
        "transforms.json".into(),
        serde_json::to_vec_pretty(&t).unwrap(),
    ));
    files
}

/// ARKitScenes raw: `<video>/<video>_frames/{lowres_wide,lowres_depth,lowres_wide_intrinsics}`
/// and `lowres_wide.traj` (world-to-camera angle-axis + translation per line).
pub fn arkit(scene: &SynthScene) -> Files {
    let vid = "41069021";
    let base = format!("{vid}/{vid}_frames/");
    let mut files = Vec::new();
    let mut traj = String::new();
    let k = scene.color_intrinsics;
    for (i, f) in scene.frames.iter().enumerate() {
        let t = frame_time(i) - 1305031000.0;
        let stem = format!("{vid}_{t:.3}");
        files.push((
            format!("{base}lowres_wide/{stem}.png"),
            png_rgb(&read(scene, &format!("color/{}.jpg", f.name))),
        ));
        let (w, h, mm) = depth_mm(scene, &f.name);
        files.push((format!("{base}lowres_depth/{stem}.png"), png16(w, h, mm)));
        files.push((
            format!("{base}lowres_wide_intrinsics/{stem}.pincam"),
            format!(
                "{} {} {} {} {} {}\n",
                k.width, k.height, k.fx, k.fy, k.cx, k.cy
            )
            .into_bytes(),
        ));
        let p = pose(scene, i);
        let w2c = p.try_inverse().unwrap();
        let r = Rotation3::from_matrix(&w2c.fixed_view::<3, 3>(0, 0).into_owned());
        let aa = r.scaled_axis();
        for dt in [-0.004, 0.004] {
            traj.push_str(&format!(
                "{:.3} {} {} {} {} {} {}\n",
                t + dt,
                aa.x,
                aa.y,
                aa.z,
                w2c[(0, 3)],
                w2c[(1, 3)],
                w2c[(2, 3)]
            ));
        }
    }
    files.push((format!("{base}lowres_wide.traj"), traj.into_bytes()));
    files.extend(instances(scene, &base));
    files
}

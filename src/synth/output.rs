//! Writing a scene directory in layout §1a or §1b of FORMATS.md, and its tar archive.

use super::Layout;
use crate::geometry::Intrinsics;
use anyhow::{Context, Result};
use image::codecs::jpeg::JpegEncoder;
use image::{ImageBuffer, Luma};
use nalgebra::Matrix4;
use std::collections::BTreeMap;
use std::fs;
use std::path::{Path, PathBuf};

/// Paths of one scene directory.
pub(crate) struct SceneWriter {
    dir: PathBuf,
    layout: Layout,
}

/// A 4x4 matrix as four whitespace-separated rows.
pub(crate) fn matrix_text(m: &Matrix4<f64>) -> String {
    let mut s = String::new();
    for r in 0..4 {
        let row: Vec<String> = (0..4).map(|c| format!("{:.6}", m[(r, c)])).collect();
        s.push_str(&row.join(" "));
        s.push('\n');
    }
    s
}

fn k_matrix(k: &Intrinsics) -> Matrix4<f64> {
    let mut m = Matrix4::identity();
    m[(0, 0)] = k.fx;
    m[(1, 1)] = k.fy;
    m[(0, 2)] = k.cx;
    m[(1, 2)] = k.cy;
    m
}

fn write(path: &Path, bytes: &[u8]) -> Result<()> {
    fs::write(path, bytes).with_context(|| format!("synth: cannot write {}", path.display()))
}

impl SceneWriter {
    /// Create the directory tree (any previous content of the scene directory is replaced).
    pub fn create(dir: &Path, layout: Layout) -> Result<Self> {
        if dir.exists() {
            fs::remove_dir_all(dir)?;
        }
        let subs: &[&str] = match layout {
            Layout::Scannet => &["color", "depth", "pose", "intrinsic", "instance"],
            Layout::PosedImages => &["instance"],
        };
        for s in subs {
            fs::create_dir_all(dir.join(s))?;
        }
        Ok(Self {
            dir: dir.to_path_buf(),
            layout,
        })
    }

    /// Intrinsics, axis alignment (world -> aligned) and instance labels (id, label).
    pub fn write_static(
        &self,
        align: &Matrix4<f64>,
        labels: &[(u32, &str)],
        color_k: &Intrinsics,
        depth_k: &Intrinsics,
    ) -> Result<()> {
        match self.layout {
            Layout::Scannet => {
                write(
                    &self.dir.join("intrinsic/intrinsic_color.txt"),
                    matrix_text(&k_matrix(color_k)).as_bytes(),
                )?;
                write(
                    &self.dir.join("intrinsic/intrinsic_depth.txt"),
                    matrix_text(&k_matrix(depth_k)).as_bytes(),
                )?;
                write(
                    &self.dir.join("intrinsic/extrinsic_color.txt"),
                    matrix_text(&Matrix4::identity()).as_bytes(),
                )?;
                write(
                    &self.dir.join("intrinsic/extrinsic_depth.txt"),
                    matrix_text(&Matrix4::identity()).as_bytes(),
                )?;
            }
            Layout::PosedImages => write(
                &self.dir.join("intrinsic.txt"),
                matrix_text(&k_matrix(color_k)).as_bytes(),
            )?,
        }
        write(
            &self.dir.join("axis_align_matrix.txt"),
            matrix_text(align).as_bytes(),
        )?;
        let labels: BTreeMap<u32, &str> = labels.iter().copied().collect();
        let labels: serde_json::Map<String, serde_json::Value> = labels
            .into_iter()
            .map(|(k, v)| (k.to_string(), v.into()))
            .collect();
        write(
            &self.dir.join("instance/labels.json"),
            serde_json::to_string_pretty(&labels)?.as_bytes(),
        )
    }

    fn frame_path(&self, kind: &str, name: &str, ext: &str) -> PathBuf {
        match (self.layout, kind) {
            (_, "instance") => self.dir.join("instance").join(format!("{name}.png")),
            (Layout::Scannet, _) => self.dir.join(kind).join(format!("{name}.{ext}")),
            (Layout::PosedImages, _) => self.dir.join(format!("{name}.{ext}")),
        }
    }

    /// Colour JPEG, depth PNG (u16 mm), instance PNG (u16 ids) and pose (`None` → inf).
    #[allow(clippy::too_many_arguments)]
    pub fn write_frame(
        &self,
        name: &str,
        rgb: &[u8],
        ck: &Intrinsics,
        depth_mm: &[u16],
        dk: &Intrinsics,
        instance: &[u16],
        pose: Option<&Matrix4<f64>>,
        quality: u8,
    ) -> Result<()> {
        let mut jpg = Vec::new();
        JpegEncoder::new_with_quality(&mut jpg, quality)
            .encode(rgb, ck.width, ck.height, image::ExtendedColorType::Rgb8)
            .context("synth: JPEG encoding failed")?;
        write(&self.frame_path("color", name, "jpg"), &jpg)?;
        save_u16(
            &self.frame_path("depth", name, "png"),
            dk.width,
            dk.height,
            depth_mm,
        )?;
        save_u16(
            &self.frame_path("instance", name, "png"),
            ck.width,
            ck.height,
            instance,
        )?;
        let text = match pose {
            Some(p) => matrix_text(p),
            None => "-inf -inf -inf -inf\n".repeat(4),
        };
        write(&self.frame_path("pose", name, "txt"), text.as_bytes())
    }
}

fn save_u16(path: &Path, w: u32, h: u32, data: &[u16]) -> Result<()> {
    let img: ImageBuffer<Luma<u16>, Vec<u16>> =
        ImageBuffer::from_raw(w, h, data.to_vec()).context("synth: image buffer size mismatch")?;
    img.save_with_format(path, image::ImageFormat::Png)
        .with_context(|| format!("synth: cannot write {}", path.display()))
}

/// Every file under `dir`, sorted, as paths relative to `dir`.
fn files_sorted(dir: &Path) -> Result<Vec<PathBuf>> {
    let mut out = Vec::new();
    let mut stack = vec![PathBuf::new()];
    while let Some(rel) = stack.pop() {
        for e in fs::read_dir(dir.join(&rel))? {
            let e = e?;
            let r = rel.join(e.file_name());
            if e.file_type()?.is_dir() {
                stack.push(r);
            } else {
                out.push(r);
            }
        }
    }
    out.sort();
    Ok(out)
}

/// Write `<out_dir>/<scene_id>.tar` holding `<scene_id>/...` with fixed metadata, so the
/// archive is byte-identical for identical content.
pub(crate) fn write_tar(dir: &Path, out_dir: &Path, scene_id: &str) -> Result<PathBuf> {
    let path = out_dir.join(format!("{scene_id}.tar"));
    let file = fs::File::create(&path)
        .with_context(|| format!("synth: cannot create {}", path.display()))?;
    let mut b = tar::Builder::new(std::io::BufWriter::new(file));
    for rel in files_sorted(dir)? {
        let data = fs::read(dir.join(&rel))?;
        let mut h = tar::Header::new_gnu();
        h.set_size(data.len() as u64);
        h.set_mode(0o644);
        h.set_mtime(0);
        h.set_uid(0);
        h.set_gid(0);
        h.set_cksum();
        b.append_data(&mut h, Path::new(scene_id).join(&rel), data.as_slice())?;
    }
    b.into_inner()?
        .into_inner()
        .map_err(|e| e.into_error())
        .with_context(|| format!("synth: cannot write {}", path.display()))?;
    Ok(path)
}

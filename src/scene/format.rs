//! Reading a scene directory in either FORMATS §1 layout: layout detection, frame listing,
//! matrix files.

use nalgebra::Matrix4;
use std::path::{Path, PathBuf};

use super::SceneError;

/// Which on-disk layout a scene directory uses.
#[derive(Debug, Clone, Copy, PartialEq, Eq, serde::Serialize)]
#[serde(rename_all = "lowercase")]
pub enum Layout {
    /// §1a: color/, depth/, pose/, intrinsic/.
    Scannet,
    /// §1b: one folder of <frame>.jpg/.png/.txt and intrinsic.txt.
    Posed,
}

impl Layout {
    pub fn as_str(&self) -> &'static str {
        match self {
            Layout::Scannet => "scannet",
            Layout::Posed => "posed",
        }
    }
}

/// The files of one frame.
#[derive(Debug, Clone)]
pub struct FrameFiles {
    pub name: String,
    pub number: u64,
    pub color: PathBuf,
    pub depth: Option<PathBuf>,
    pub pose: Option<PathBuf>,
    pub instance: Option<PathBuf>,
}

/// The files of a scene directory, frames in numeric order.
#[derive(Debug, Clone)]
pub struct SceneFiles {
    pub root: PathBuf,
    pub layout: Layout,
    pub frames: Vec<FrameFiles>,
    pub intrinsic_color: PathBuf,
    pub intrinsic_depth: Option<PathBuf>,
    pub axis_align: Option<PathBuf>,
    pub instance_labels: Option<PathBuf>,
}

/// Parse a whitespace-separated 4x4 row-major matrix (a 3x3 is accepted and padded).
/// Non-finite values ("nan", "inf", "-inf") are parsed; callers decide what they mean.
pub fn parse_matrix(text: &str, what: &str) -> Result<Matrix4<f64>, SceneError> {
    let nums: Result<Vec<f64>, _> = text.split_whitespace().map(|t| t.parse::<f64>()).collect();
    let nums = nums.map_err(|_| {
        SceneError::Malformed(format!(
            "{what}: expected numbers, found {:?}",
            first_bad(text)
        ))
    })?;
    match nums.len() {
        16 => Ok(Matrix4::from_row_slice(&nums)),
        9 => {
            let mut m = Matrix4::identity();
            for r in 0..3 {
                for c in 0..3 {
                    m[(r, c)] = nums[r * 3 + c];
                }
            }
            Ok(m)
        }
        n => Err(SceneError::Malformed(format!(
            "{what}: expected a 4x4 matrix (16 numbers), found {n}"
        ))),
    }
}

/// ScanNet's `<scene>.txt` style: a line `axisAlignment = 16 numbers` is also accepted.
pub fn parse_axis_align(text: &str, what: &str) -> Result<Matrix4<f64>, SceneError> {
    for line in text.lines() {
        if let Some(rest) = line.trim().strip_prefix("axisAlignment") {
            return parse_matrix(rest.trim_start().trim_start_matches('='), what);
        }
    }
    parse_matrix(text, what)
}

fn first_bad(text: &str) -> String {
    text.split_whitespace()
        .find(|t| t.parse::<f64>().is_err())
        .unwrap_or("")
        .chars()
        .take(32)
        .collect()
}

pub fn read_matrix(path: &Path, what: &str) -> Result<Matrix4<f64>, SceneError> {
    let text = std::fs::read_to_string(path)
        .map_err(|e| SceneError::Malformed(format!("{what}: cannot read: {e}")))?;
    parse_matrix(&text, what)
}

/// Decimal frame number of a file stem, if it is one.
fn frame_number(stem: &str) -> Option<u64> {
    if stem.is_empty() || !stem.bytes().all(|b| b.is_ascii_digit()) {
        return None;
    }
    stem.parse().ok()
}

fn stems_with_ext(dir: &Path, exts: &[&str]) -> Result<Vec<(u64, String, PathBuf)>, SceneError> {
    let mut out = Vec::new();
    let rd = match std::fs::read_dir(dir) {
        Ok(rd) => rd,
        Err(_) => return Ok(out),
    };
    for entry in rd.flatten() {
        let path = entry.path();
        if !path.is_file() {
            continue;
        }
        let ext = path
            .extension()
            .and_then(|e| e.to_str())
            .map(|e| e.to_ascii_lowercase());
        let Some(ext) = ext else { continue };
        if !exts.contains(&ext.as_str()) {
            continue;
        }
        let Some(stem) = path
            .file_stem()
            .and_then(|s| s.to_str())
            .map(str::to_string)
        else {
            continue;
        };
        if let Some(n) = frame_number(&stem) {
            out.push((n, stem, path));
        }
    }
    out.sort_by(|a, b| a.0.cmp(&b.0).then(a.1.cmp(&b.1)));
    Ok(out)
}

/// Find the scene root inside an unpacked archive: the folder itself when it holds a scene,
/// else its single sub-folder.
pub fn find_scene_root(dir: &Path) -> Result<PathBuf, SceneError> {
    if detect_layout(dir).is_some() {
        return Ok(dir.to_path_buf());
    }
    let subdirs: Vec<PathBuf> = std::fs::read_dir(dir)
        .map_err(|e| SceneError::Malformed(format!("cannot list archive contents: {e}")))?
        .flatten()
        .map(|e| e.path())
        .filter(|p| {
            p.is_dir()
                && !p
                    .file_name()
                    .is_some_and(|n| n.to_string_lossy().starts_with("__MACOSX"))
        })
        .collect();
    if subdirs.len() == 1 && detect_layout(&subdirs[0]).is_some() {
        return Ok(subdirs[0].clone());
    }
    Err(SceneError::NoScene)
}

fn detect_layout(dir: &Path) -> Option<Layout> {
    if dir.join("color").is_dir() || dir.join("intrinsic").is_dir() {
        return Some(Layout::Scannet);
    }
    if dir.join("intrinsic.txt").is_file() {
        return Some(Layout::Posed);
    }
    None
}

/// List a scene directory's files, checking that every colour frame has depth and pose.
pub fn scan(root: &Path) -> Result<SceneFiles, SceneError> {
    let layout = detect_layout(root).ok_or(SceneError::NoScene)?;
    let (color_dir, depth_dir, pose_dir, intr, intr_d) = match layout {
        Layout::Scannet => (
            root.join("color"),
            root.join("depth"),
            root.join("pose"),
            root.join("intrinsic").join("intrinsic_color.txt"),
            Some(root.join("intrinsic").join("intrinsic_depth.txt")),
        ),
        Layout::Posed => (
            root.to_path_buf(),
            root.to_path_buf(),
            root.to_path_buf(),
            root.join("intrinsic.txt"),
            None,
        ),
    };
    if !intr.is_file() {
        return Err(SceneError::Malformed(format!(
            "missing colour intrinsics ({})",
            intr.strip_prefix(root).unwrap_or(&intr).display()
        )));
    }
    let colors = stems_with_ext(&color_dir, &["jpg", "jpeg"])?;
    if colors.is_empty() {
        return Err(SceneError::NoFrames);
    }
    let depth_ext: &[&str] = &["png"];
    let depths = stems_with_ext(&depth_dir, depth_ext)?;
    let poses = stems_with_ext(&pose_dir, &["txt"])?;
    let instance_dir = root.join("instance");
    let instances = if layout == Layout::Scannet {
        stems_with_ext(&instance_dir, &["png"])?
    } else {
        Vec::new()
    };
    let find = |list: &[(u64, String, PathBuf)], stem: &str| {
        list.iter().find(|x| x.1 == stem).map(|x| x.2.clone())
    };
    let mut frames = Vec::with_capacity(colors.len());
    for (n, stem, path) in colors {
        let depth = find(&depths, &stem);
        let pose = find(&poses, &stem);
        if depth.is_none() {
            return Err(SceneError::Malformed(format!(
                "frame {stem}: colour image has no depth image"
            )));
        }
        if pose.is_none() {
            return Err(SceneError::Malformed(format!(
                "frame {stem}: colour image has no pose file"
            )));
        }
        frames.push(FrameFiles {
            name: stem.clone(),
            number: n,
            color: path,
            depth,
            pose,
            instance: find(&instances, &stem),
        });
    }
    let axis = root.join("axis_align_matrix.txt");
    let labels = instance_dir.join("labels.json");
    Ok(SceneFiles {
        root: root.to_path_buf(),
        layout,
        frames,
        intrinsic_color: intr,
        intrinsic_depth: intr_d.filter(|p| p.is_file()),
        axis_align: axis.is_file().then_some(axis),
        instance_labels: labels.is_file().then_some(labels),
    })
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn parses_matrices_and_reports_bad_tokens() {
        let m = parse_matrix("1 0 0 1\n0 1 0 2\n0 0 1 3\n0 0 0 1\n", "pose").unwrap();
        assert_eq!(m[(0, 3)], 1.0);
        assert_eq!(m[(2, 3)], 3.0);
        let inf = parse_matrix("-inf -inf -inf -inf 0 0 0 0 0 0 0 0 0 0 0 1", "pose").unwrap();
        assert!(inf[(0, 0)].is_infinite());
        let e = parse_matrix("1 0 x 0", "pose 7").unwrap_err().to_string();
        assert!(e.contains("pose 7") && e.contains("\"x\""), "{e}");
        let e = parse_matrix("1 2 3", "K").unwrap_err().to_string();
        assert!(e.contains("found 3"), "{e}");
        let a =
            parse_axis_align("axisAlignment = 1 0 0 5 0 1 0 0 0 0 1 0 0 0 0 1\n", "align").unwrap();
        assert_eq!(a[(0, 3)], 5.0);
    }
}

//! Scene ingest: an uploaded archive (already spooled to a file under the data dir) is
//! unpacked, validated and stored. Nothing is left behind on failure, and the scene row
//! appears only once every file is in place.

use std::path::{Path, PathBuf};

use crate::scene::archive::{self, ArchiveKind, Limits};
use crate::scene::formats::{self, sens, CaptureFormat, FormatOptions};
use crate::scene::import::{self, ImportedScene};
use crate::scene::{format, SceneError};

/// What the uploader said about the body: a named capture format (None: detect) and its
/// settings.
#[derive(Debug, Clone, Copy, Default)]
pub struct Capture {
    pub format: Option<CaptureFormat>,
    pub opts: FormatOptions,
}

/// The scene's name for a converted capture: the `.sens` file's stem, else the capture
/// folder's name unless it is the unpack folder itself.
fn scene_name(f: CaptureFormat, input: &Path, unpacked: &Path) -> String {
    if f == CaptureFormat::Sens {
        if let Ok(Some(p)) = sens::find_sens(input) {
            if let Some(s) = p.file_stem() {
                return s.to_string_lossy().into_owned();
            }
        }
    }
    if input == unpacked {
        return "scene".into();
    }
    input
        .file_name()
        .map(|n| n.to_string_lossy().into_owned())
        .unwrap_or_else(|| "scene".into())
}

/// Removes a path when dropped unless disarmed.
pub struct Cleanup(pub Option<PathBuf>);

impl Drop for Cleanup {
    fn drop(&mut self) {
        if let Some(p) = self.0.take() {
            let _ = if p.is_dir() {
                std::fs::remove_dir_all(&p)
            } else {
                std::fs::remove_file(&p)
            };
        }
    }
}

impl Cleanup {
    pub fn disarm(&mut self) {
        self.0 = None;
    }
}

/// Unpack, validate and lay out a scene's files under `scene_dir`; returns what the store
/// records. `scene_dir` is removed again on any error.
pub fn prepare_scene(
    upload: &Path,
    content_type: Option<&str>,
    work_dir: &Path,
    scene_dir: &Path,
    limits: Limits,
    capture: &Capture,
) -> Result<ImportedScene, SceneError> {
    let mut head = [0u8; 512];
    let n = {
        use std::io::Read;
        let mut f = std::fs::File::open(upload)
            .map_err(|e| SceneError::Io(format!("cannot reopen upload: {e}")))?;
        let mut total = 0;
        while total < head.len() {
            let k = f
                .read(&mut head[total..])
                .map_err(|e| SceneError::Io(format!("cannot read upload: {e}")))?;
            if k == 0 {
                break;
            }
            total += k;
        }
        total
    };
    if n == 0 {
        // (an empty body is never a capture either)
        return Err(SceneError::NotArchive(
            "the request body is empty; send a tar, tar.gz or zip archive of one scene".into(),
        ));
    }
    std::fs::create_dir_all(work_dir)
        .map_err(|e| SceneError::Io(format!("cannot create work dir: {e}")))?;
    let _work = Cleanup(Some(work_dir.to_path_buf()));
    let opts = FormatOptions {
        max_bytes: limits.max_bytes,
        max_pixels: limits.max_image_pixels,
        ..capture.opts
    };
    let raw_sens = capture.format == Some(CaptureFormat::Sens) && sens::looks_like_sens(&head[..n])
        || (capture.format.is_none()
            && archive::sniff(&head[..n], content_type).is_err()
            && sens::looks_like_sens(&head[..n]));
    let (root, format_used) = if raw_sens {
        let out = work_dir.join("converted").join("scene");
        formats::convert(CaptureFormat::Sens, upload, &out, &opts)?;
        (out, Some(CaptureFormat::Sens))
    } else {
        let kind: ArchiveKind = archive::sniff(&head[..n], content_type)?;
        let unpacked = work_dir.join("in");
        std::fs::create_dir_all(&unpacked)
            .map_err(|e| SceneError::Io(format!("cannot create work dir: {e}")))?;
        archive::unpack(upload, kind, &unpacked, limits)?;
        let found = formats::detect(&unpacked);
        let chosen = match (capture.format, found) {
            (Some(f), Some((g, root))) if f == g => Some((f, root)),
            (Some(f), _) => Some((f, formats::single_folder(&unpacked))),
            (None, found) => found,
        };
        match chosen {
            Some((f, input)) => {
                let name = scene_name(f, &input, &unpacked);
                let out = work_dir.join("converted").join(name);
                formats::convert(f, &input, &out, &opts)?;
                (out, Some(f))
            }
            None => (format::find_scene_root(&unpacked)?, None),
        }
    };
    let files = format::scan(&root)?;
    import::check_scene_pixels(&files, limits.max_image_pixels, limits.max_scene_pixels)?;
    let mut scene = import::import(
        &files,
        work_dir.join("converted").as_path(),
        limits.max_image_pixels,
    )?;
    if format_used.is_none() {
        // A §1 layout: its folder name, unless the archive had no top folder.
        scene.name = if root == work_dir.join("in") {
            "scene".into()
        } else {
            scene.name.clone()
        };
    }
    scene.format = format_used;

    let mut guard = Cleanup(Some(scene_dir.to_path_buf()));
    let color_dir = scene_dir.join("color");
    std::fs::create_dir_all(&color_dir)
        .map_err(|e| SceneError::Io(format!("cannot create scene dir: {e}")))?;
    let mut has_instance = false;
    for f in &mut scene.frames {
        let dest = color_dir.join(format!("{}.jpg", f.idx));
        std::fs::rename(&f.color_path, &dest)
            .map_err(|e| SceneError::Io(format!("cannot store frame {}: {e}", f.name)))?;
        f.color_path = dest;
        if let Some(inst) = f.instance_path.take() {
            let dir = scene_dir.join("instance");
            std::fs::create_dir_all(&dir)
                .map_err(|e| SceneError::Io(format!("cannot create instance dir: {e}")))?;
            let dest = dir.join(format!("{}.png", f.idx));
            std::fs::rename(&inst, &dest).map_err(|e| {
                SceneError::Io(format!("cannot store instance mask {}: {e}", f.name))
            })?;
            f.instance_path = Some(dest);
            has_instance = true;
        }
    }
    if let (true, Some(labels)) = (has_instance, scene.instance_labels.take()) {
        let text = std::fs::read_to_string(&labels)
            .map_err(|e| SceneError::Malformed(format!("instance/labels.json: {e}")))?;
        let parsed: std::collections::BTreeMap<String, String> = serde_json::from_str(&text)
            .map_err(|e| {
                SceneError::Malformed(format!(
                    "instance/labels.json is not a JSON object of id -> label: {e}"
                ))
            })?;
        let dest = scene_dir.join("instance").join("labels.json");
        std::fs::write(&dest, serde_json::to_vec(&parsed).unwrap_or_default())
            .map_err(|e| SceneError::Io(format!("cannot store labels: {e}")))?;
        scene.instance_labels = Some(dest);
    }
    guard.disarm();
    Ok(scene)
}

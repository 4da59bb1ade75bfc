//! ScanNet ground-truth boxes: mesh vertices (`<scene>_vh_clean_2.ply`), over-segmentation
//! (`<scene>_vh_clean_2.0.010000.segs.json`), object groups (`<scene>.aggregation.json`)
//! and the axis alignment (`<scene>.txt`). Box = AABB of the aligned vertices of each
//! object; object ids are the aggregation's `objectId` (the ids ScanRefer and Nr3D use).

use crate::eval::dataset::{write_dataset, SceneObject, SceneObjects};
use crate::geometry::Aabb;
use anyhow::{bail, Context, Result};
use nalgebra::{Matrix4, Point3};
use serde::Deserialize;
use std::path::Path;

/// Read the vertex positions of a PLY file (ascii or binary little endian).
pub fn read_ply_vertices(bytes: &[u8]) -> Result<Vec<[f64; 3]>> {
    let end = find(bytes, b"end_header").context("not a PLY file: no end_header")?;
    let mut body = end + b"end_header".len();
    if bytes.get(body) == Some(&b'\r') {
        body += 1;
    }
    if bytes.get(body) != Some(&b'\n') {
        bail!("PLY header does not end with a newline");
    }
    body += 1;
    let header = std::str::from_utf8(&bytes[..end]).context("PLY header is not text")?;
    let mut lines = header.lines().map(str::trim);
    if lines.next() != Some("ply") {
        bail!("not a PLY file: missing magic");
    }
    let mut format = "";
    let mut n_vertex: Option<usize> = None;
    let mut props: Vec<(String, String)> = Vec::new(); // vertex properties: (type, name)
    let mut in_vertex = false;
    let mut before_vertex_bytes = false;
    for l in lines {
        let f: Vec<&str> = l.split_whitespace().collect();
        match f.as_slice() {
            ["format", fmt, ..] => format = fmt,
            ["element", "vertex", n] => {
                n_vertex = Some(n.parse().context("bad vertex count in PLY header")?);
                in_vertex = true;
            }
            ["element", _, n] => {
                if n_vertex.is_none() && n.parse::<usize>().unwrap_or(0) > 0 {
                    before_vertex_bytes = true;
                }
                in_vertex = false;
            }
            ["property", "list", ..] if in_vertex => bail!("PLY vertex lists are not supported"),
            ["property", ty, name] if in_vertex => props.push((ty.to_string(), name.to_string())),
            _ => {}
        }
    }
    let n = n_vertex.context("PLY has no vertex element")?;
    if before_vertex_bytes {
        bail!("PLY elements before the vertices are not supported");
    }
    let pos = |name: &str| {
        props
            .iter()
            .position(|p| p.1 == name)
            .with_context(|| format!("PLY vertices have no {name}"))
    };
    let idx = [pos("x")?, pos("y")?, pos("z")?];
    match format {
        "ascii" => {
            let text = std::str::from_utf8(&bytes[body..]).context("ascii PLY body is not text")?;
            let mut out = Vec::with_capacity(n);
            for (i, line) in text
                .lines()
                .filter(|l| !l.trim().is_empty())
                .take(n)
                .enumerate()
            {
                let v: Vec<&str> = line.split_whitespace().collect();
                let g = |k: usize| -> Result<f64> {
                    v.get(k)
                        .and_then(|s| s.parse().ok())
                        .with_context(|| format!("PLY vertex {i}: bad value"))
                };
                out.push([g(idx[0])?, g(idx[1])?, g(idx[2])?]);
            }
            if out.len() != n {
                bail!("PLY has {} vertices, header says {n}", out.len());
            }
            Ok(out)
        }
        "binary_little_endian" => {
            let sizes: Vec<usize> = props
                .iter()
                .map(|p| type_size(&p.0))
                .collect::<Result<_>>()?;
            let stride: usize = sizes.iter().sum();
            let offs: Vec<usize> = sizes
                .iter()
                .scan(0, |acc, s| {
                    let o = *acc;
                    *acc += s;
                    Some(o)
                })
                .collect();
            let need = n.checked_mul(stride).context("PLY too large")?;
            let data = bytes
                .get(body..body + need)
                .context("PLY is truncated: fewer vertex bytes than the header says")?;
            let read = |rec: &[u8], k: usize| -> Result<f64> {
                let b = &rec[offs[k]..offs[k] + sizes[k]];
                Ok(match props[k].0.as_str() {
                    "float" | "float32" => f32::from_le_bytes(b.try_into()?) as f64,
                    "double" | "float64" => f64::from_le_bytes(b.try_into()?),
                    t => bail!("PLY coordinate type {t} is not supported"),
                })
            };
            data.chunks_exact(stride)
                .map(|rec| Ok([read(rec, idx[0])?, read(rec, idx[1])?, read(rec, idx[2])?]))
                .collect()
        }
        f => bail!("PLY format {f:?} is not supported (ascii or binary_little_endian)"),
    }
}

fn type_size(t: &str) -> Result<usize> {
    Ok(match t {
        "char" | "uchar" | "int8" | "uint8" => 1,
        "short" | "ushort" | "int16" | "uint16" => 2,
        "int" | "uint" | "float" | "int32" | "uint32" | "float32" => 4,
        "double" | "float64" => 8,
        _ => bail!("unknown PLY property type {t}"),
    })
}

fn find(hay: &[u8], needle: &[u8]) -> Option<usize> {
    hay.windows(needle.len()).position(|w| w == needle)
}

/// `axisAlignment = m00 ... m33` (row-major) from a ScanNet `<scene>.txt`; identity if absent.
pub fn parse_axis_alignment(text: &str) -> Result<Matrix4<f64>> {
    for line in text.lines() {
        if let Some((k, v)) = line.split_once('=') {
            if k.trim() == "axisAlignment" {
                let vals: Vec<f64> = v
                    .split_whitespace()
                    .map(|s| s.parse::<f64>())
                    .collect::<Result<_, _>>()
                    .context("axisAlignment has a non-numeric value")?;
                if vals.len() != 16 {
                    bail!("axisAlignment has {} numbers, expected 16", vals.len());
                }
                return Ok(Matrix4::from_row_slice(&vals));
            }
        }
    }
    Ok(Matrix4::identity())
}

#[derive(Deserialize)]
struct Segs {
    #[serde(rename = "segIndices")]
    seg_indices: Vec<i64>,
}

#[derive(Deserialize)]
struct Aggregation {
    #[serde(rename = "segGroups")]
    seg_groups: Vec<SegGroup>,
}

#[derive(Deserialize)]
struct SegGroup {
    #[serde(rename = "objectId", default)]
    object_id: Option<u32>,
    #[serde(default)]
    id: Option<u32>,
    label: String,
    segments: Vec<i64>,
}

fn read(path: &Path) -> Result<Vec<u8>> {
    std::fs::read(path).with_context(|| format!("cannot read {}", path.display()))
}

/// Ground-truth objects of one ScanNet scan folder.
pub fn scene_objects(scan_dir: &Path, scene_id: &str) -> Result<SceneObjects> {
    let ply = read_ply_vertices(&read(&scan_dir.join(format!("{scene_id}_vh_clean_2.ply")))?)
        .with_context(|| format!("{scene_id}_vh_clean_2.ply"))?;
    let segs_path = scan_dir.join(format!("{scene_id}_vh_clean_2.0.010000.segs.json"));
    let segs: Segs = serde_json::from_slice(&read(&segs_path)?)
        .with_context(|| format!("{} is not a segs file", segs_path.display()))?;
    if segs.seg_indices.len() != ply.len() {
        bail!(
            "{}: {} segment indices for {} vertices",
            segs_path.display(),
            segs.seg_indices.len(),
            ply.len()
        );
    }
    let agg_path = [
        format!("{scene_id}.aggregation.json"),
        format!("{scene_id}_vh_clean.aggregation.json"),
    ]
    .iter()
    .map(|n| scan_dir.join(n))
    .find(|p| p.is_file())
    .with_context(|| format!("no {scene_id}.aggregation.json in {}", scan_dir.display()))?;
    let agg: Aggregation = serde_json::from_slice(&read(&agg_path)?)
        .with_context(|| format!("{} is not an aggregation file", agg_path.display()))?;
    let meta = scan_dir.join(format!("{scene_id}.txt"));
    let align = if meta.is_file() {
        parse_axis_alignment(&String::from_utf8_lossy(&read(&meta)?))
            .with_context(|| format!("in {}", meta.display()))?
    } else {
        Matrix4::identity()
    };
    let mut by_seg: std::collections::HashMap<i64, Vec<usize>> = std::collections::HashMap::new();
    for (v, s) in segs.seg_indices.iter().enumerate() {
        by_seg.entry(*s).or_default().push(v);
    }
    let mut objects = Vec::new();
    for g in &agg.seg_groups {
        let pts: Vec<Point3<f64>> = g
            .segments
            .iter()
            .filter_map(|s| by_seg.get(s))
            .flatten()
            .map(|&v| align.transform_point(&Point3::from(ply[v])))
            .collect();
        let id = g
            .object_id
            .or(g.id)
            .with_context(|| format!("{}: a segGroup has no objectId", agg_path.display()))?;
        if let Some(aabb) = Aabb::from_points(&pts) {
            objects.push(SceneObject {
                id,
                label: g.label.clone(),
                aabb,
            });
        }
    }
    objects.sort_by_key(|o| o.id);
    Ok(SceneObjects {
        scene_id: scene_id.to_string(),
        objects,
    })
}

/// Convert the chosen scenes (all sub-folders when `scenes` is empty) into `out/objects/`.
pub fn convert_scans(scans: &Path, scenes: &[String], out: &Path) -> Result<usize> {
    let ids: Vec<String> = if scenes.is_empty() {
        let mut v: Vec<String> = std::fs::read_dir(scans)
            .with_context(|| format!("cannot list {}", scans.display()))?
            .filter_map(|e| e.ok())
            .filter(|e| e.path().is_dir())
            .filter_map(|e| e.file_name().to_str().map(String::from))
            .collect();
        v.sort();
        v
    } else {
        scenes.to_vec()
    };
    if ids.is_empty() {
        bail!("no scan folders in {}", scans.display());
    }
    let mut all = Vec::new();
    for id in &ids {
        all.push(scene_objects(&scans.join(id), id).with_context(|| format!("scene {id}"))?);
    }
    write_dataset(out, &all, &[])?;
    Ok(all.len())
}

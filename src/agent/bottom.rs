//! The bottom of a box that support completion left in the air (no layer found below it):
//! a base hidden behind an edge above the eye ([`crate::geometry::hidden_base`]), else the
//! floor that every view's 2D box reaches ([`crate::geometry::floor_reach`]), else as far
//! down as the chosen view's 2D box shows the object
//! ([`crate::geometry::floor_reach::lower_to_box_edge`]).

use super::ensemble_boxes::BoxFrom;
use crate::geometry::floor_reach::{
    extend_to_floor_reach, lower_to_box_edge, read_view, EdgeReach, FloorReach,
};
use crate::geometry::fusion::SegmentedView;
use crate::geometry::hidden_base::{extend_to_hidden_base, HiddenBase};
use crate::geometry::{Aabb, GeometryParams};

/// The views the box came from.
pub struct BottomViews<'a> {
    pub anchor: &'a SegmentedView<'a>,
    /// The chosen view's box when it came from an image (a detection or the VLM's box).
    pub anchor_box: Option<[f32; 4]>,
    /// The other segmented views.
    pub views: &'a [SegmentedView<'a>],
    /// Each view's box and where it came from.
    pub boxes: &'a [(usize, [f32; 4], BoxFrom)],
    /// Did the fusion keep view `i`?
    pub kept: &'a dyn Fn(usize) -> bool,
}

/// What each step of [`complete`] did (`None` for a step turned off or not reached).
#[derive(Debug, Default)]
pub struct BottomRecord {
    pub hidden: Option<HiddenBase>,
    pub reach: Option<FloorReach>,
    pub edge: Option<EdgeReach>,
}

/// `b` with its bottom completed (see the module documentation), and what each step did.
/// `floor`: the room's floor height.
pub fn complete(
    b: &Aabb,
    v: &BottomViews<'_>,
    floor: Option<f64>,
    params: &GeometryParams,
) -> (Aabb, BottomRecord) {
    let mut record = BottomRecord::default();
    let used: Vec<&SegmentedView> = std::iter::once(v.anchor)
        .chain(v.views.iter().filter(|s| (v.kept)(s.index)))
        .collect();
    let (b, hidden) = if params.support.hidden_base {
        extend_to_hidden_base(b, &used, params)
    } else {
        (*b, None)
    };
    let moved = hidden.as_ref().is_some_and(|h| h.to != h.from);
    record.hidden = hidden;
    if moved {
        return (b, record);
    }
    let b = match floor.filter(|_| params.support.floor_reach) {
        Some(floor) => {
            // Boxes drawn on the image only: a candidate's or a footprint's box comes from
            // the same depth that missed the thin part.
            let image_box = |i: usize| {
                v.boxes
                    .iter()
                    .find(|(k, _, from)| {
                        *k == i && matches!(from, BoxFrom::Detection | BoxFrom::VlmBox)
                    })
                    .map(|(_, bx, _)| *bx)
            };
            let boxed: Vec<(&SegmentedView, [f32; 4])> = v
                .anchor_box
                .map(|bx| (v.anchor, bx))
                .into_iter()
                .chain(
                    used.iter()
                        .skip(1)
                        .filter_map(|s| Some((*s, image_box(s.index)?))),
                )
                .collect();
            let (b, reach) = extend_to_floor_reach(&b, &boxed, floor, params);
            let moved = reach.as_ref().is_some_and(|r| r.to != r.from);
            record.reach = reach;
            if moved {
                return (b, record);
            }
            b
        }
        None => b,
    };
    if let Some(bx) = v.anchor_box.filter(|_| params.support.box_edge) {
        // The chosen view as floor reach read it, on this same box, when it did.
        let read = record
            .reach
            .as_ref()
            .and_then(|r| r.views.iter().find(|x| x.index == v.anchor.index))
            .cloned()
            .unwrap_or_else(|| read_view(v.anchor, bx, &b, floor, params));
        let (b, edge) = lower_to_box_edge(&b, read, floor, params);
        record.edge = edge;
        return (b, record);
    }
    (b, record)
}

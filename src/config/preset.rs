//! The `method` preset: one switch between the paper's projection and ours.

use serde::{Deserialize, Serialize};

use crate::agent::AgentParams;

/// Which method the defaults follow; individual settings still override it.
#[derive(Debug, Clone, Copy, PartialEq, Eq, Default, Serialize, Deserialize)]
#[serde(rename_all = "snake_case")]
pub enum Method {
    /// Our method: every added step on (the built-in defaults).
    #[default]
    Grounder,
    /// The paper's box: multi-view points, chamfer test at 0.1 m², outlier removal, the
    /// axis-aligned box; none of our added steps (REFERENCE-PARAMS.md).
    Paper,
}

impl Method {
    /// Set the method's defaults in `agent` (used below the file, environment and flags).
    pub fn apply(self, agent: &mut AgentParams) {
        if self == Method::Grounder {
            return;
        }
        let g = &mut agent.geometry;
        g.chamfer_threshold = 0.1;
        g.chamfer_cover_threshold = 0.0;
        g.cluster_voxel = 0.0;
        g.box_trim = 0.0;
        g.plane_iqr = 0.0;
        g.consensus.mask_votes = false;
        g.consensus.free_space = false;
        g.consensus.complement_agree = 0.0;
        g.consensus.anchor_box_bound = false;
        g.consensus.detection_bound = false;
        g.depth_fill.enabled = false;
        g.layout.enabled = false;
        g.support.enabled = false;
        g.round_back.enabled = false;
        agent.good_depth_fraction = agent.min_depth_fraction;
        agent.candidates.enabled = false;
        agent.preselect_reseen = false;
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn paper_turns_every_added_step_off_and_grounder_changes_nothing() {
        let mut a = AgentParams::default();
        Method::Grounder.apply(&mut a);
        assert_eq!(format!("{a:?}"), format!("{:?}", AgentParams::default()));
        Method::Paper.apply(&mut a);
        let g = &a.geometry;
        assert_eq!(g.chamfer_threshold, 0.1);
        assert_eq!(g.chamfer_cover_threshold, 0.0);
        assert_eq!(g.cluster_voxel, 0.0);
        assert!(!g.consensus.mask_votes && !g.consensus.free_space);
        assert_eq!(g.consensus.complement_agree, 0.0);
        assert!(!g.consensus.anchor_box_bound && !g.consensus.detection_bound);
        assert!(!g.depth_fill.enabled && !g.layout.enabled && !g.support.enabled);
        assert!(!g.round_back.enabled);
        assert!(!a.candidates.enabled && !a.preselect_reseen);
        // The paper's own settings stay as they are.
        assert_eq!((g.erode_kernel, g.keep_components, g.max_views), (15, 2, 7));
        assert_eq!((g.sor_neighbors, g.sor_std_ratio), (5, 1.0));
    }
}

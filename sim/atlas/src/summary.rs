//! What `stylet atlas inspect` reports about an atlas (docs/atlas.md "Inspect").

use serde::Serialize;

use crate::Atlas;
use crate::manifest::{InsertionPath, Provenance, ThresholdsToml};

#[derive(Debug, Clone, Serialize)]
pub struct Summary {
    pub name: String,
    pub description: String,
    pub dir: String,
    pub content_hash: String,
    pub dims: [usize; 3],
    pub spacing_mm: [f64; 3],
    /// World position of voxel (0, 0, 0) (mm, RAS).
    pub origin_mm: [f64; 3],
    pub hu_range: [f32; 2],
    pub thresholds_hu: ThresholdsToml,
    /// "atlas" (given in atlas.toml) or "estimated" (from the CT histogram).
    pub thresholds_source: String,
    pub risk_depth_mm: f64,
    pub labels: Vec<LabelSummary>,
    pub paths: Vec<InsertionPath>,
    pub provenance: Provenance,
}

#[derive(Debug, Clone, Serialize)]
pub struct LabelSummary {
    pub id: u16,
    pub name: String,
    pub role: String,
    pub tissue: String,
    /// "partial" (from the label map) or "heuristic" (h(x, 0) where the map is 0).
    pub source: String,
    pub voxels: u64,
    pub volume_ml: f64,
}

impl Summary {
    pub fn of(atlas: &Atlas) -> Self {
        let m = &atlas.model;
        let grid = m.ct().grid();
        let s = grid.spacing_mm();
        let voxel_ml = s[0] * s[1] * s[2] / 1000.0;
        let heuristic_ids = atlas.manifest.heuristic.ids();
        let counts = m.label_voxel_counts();
        let labels = m
            .label_table()
            .labels()
            .iter()
            .zip(counts)
            .map(|(l, (_, n))| LabelSummary {
                id: l.id,
                name: l.name.clone(),
                role: l.role.as_str().into(),
                tissue: l.tissue.clone(),
                source: if heuristic_ids.contains(&l.id) {
                    "heuristic"
                } else {
                    "partial"
                }
                .into(),
                voxels: n,
                volume_ml: (n as f64 * voxel_ml * 10.0).round() / 10.0,
            })
            .collect();
        let (lo, hi) = m
            .ct()
            .data()
            .iter()
            .fold((f32::INFINITY, f32::NEG_INFINITY), |(a, b), &v| (a.min(v), b.max(v)));
        let o = grid.affine().origin;
        Summary {
            name: atlas.manifest.name.clone(),
            description: atlas.manifest.description.clone(),
            dir: atlas.dir.display().to_string(),
            content_hash: atlas.content_hash.clone(),
            dims: grid.dims(),
            spacing_mm: s,
            origin_mm: [o.x, o.y, o.z],
            hu_range: [lo, hi],
            thresholds_hu: atlas.thresholds_toml(),
            thresholds_source: atlas.threshold_source.as_str().into(),
            risk_depth_mm: m.thresholds().risk_depth_mm,
            labels,
            paths: atlas.manifest.paths.clone(),
            provenance: atlas.manifest.provenance.clone(),
        }
    }

    /// A human-readable report.
    pub fn to_text(&self) -> String {
        let mut out = String::new();
        let t = &self.thresholds_hu;
        out += &format!("atlas        {} — {}\n", self.name, self.description);
        out += &format!("directory    {}\n", self.dir);
        out += &format!("content hash {}\n", self.content_hash);
        out += &format!(
            "grid         {} x {} x {} voxels, {:.3} x {:.3} x {:.3} mm, origin ({:.1}, {:.1}, {:.1}) mm RAS\n",
            self.dims[0],
            self.dims[1],
            self.dims[2],
            self.spacing_mm[0],
            self.spacing_mm[1],
            self.spacing_mm[2],
            self.origin_mm[0],
            self.origin_mm[1],
            self.origin_mm[2]
        );
        out += &format!("CT range     {:.0} … {:.0} HU\n", self.hu_range[0], self.hu_range[1]);
        out += &format!(
            "thresholds   air|skin {:.0} HU, skin|fat {:.0} HU, fat|bone {:.0} HU ({}), risk depth δ = {} mm\n",
            t.air_skin, t.skin_fat, t.fat_bone, self.thresholds_source, self.risk_depth_mm
        );
        out += &format!("source       {}\n", self.provenance.source);
        out += "labels (depth 0):\n";
        out += &format!(
            "  {:>5}  {:<34} {:<8} {:<9} {:>10} {:>10}\n",
            "id", "name", "role", "source", "voxels", "volume ml"
        );
        for l in &self.labels {
            out += &format!(
                "  {:>5}  {:<34} {:<8} {:<9} {:>10} {:>10.1}\n",
                l.id, l.name, l.role, l.source, l.voxels, l.volume_ml
            );
        }
        if !self.paths.is_empty() {
            out += "insertion paths:\n";
            for p in &self.paths {
                let len = ((p.entry_mm[0] - p.target_mm[0]).powi(2)
                    + (p.entry_mm[1] - p.target_mm[1]).powi(2)
                    + (p.entry_mm[2] - p.target_mm[2]).powi(2))
                .sqrt();
                out += &format!(
                    "  {:<20} entry ({:.1}, {:.1}, {:.1}) → target ({:.1}, {:.1}, {:.1}) mm, {:.0} mm — {}\n",
                    p.name,
                    p.entry_mm[0],
                    p.entry_mm[1],
                    p.entry_mm[2],
                    p.target_mm[0],
                    p.target_mm[1],
                    p.target_mm[2],
                    len,
                    p.description
                );
            }
        }
        out
    }
}

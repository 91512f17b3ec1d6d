//! What `stylet atlas inspect` reports about an atlas (docs/atlas.md "Inspect").

use serde::Serialize;

use crate::Atlas;
use crate::manifest::{InsertionPath, MotionKind, Provenance, ThresholdsToml};

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
    /// Where this load's skin and bone distance maps came from (the derived-data cache or a
    /// derivation), in words.
    pub distance_maps: String,
    pub labels: Vec<LabelSummary>,
    pub paths: Vec<InsertionPath>,
    pub provenance: Provenance,
    pub breathing: BreathingSummary,
}

/// The attached breathing motion and how well its inverse works (docs/breathing.md "Atlases").
#[derive(Debug, Clone, Serialize)]
pub struct BreathingSummary {
    pub motion: MotionKind,
    pub amplitude_mm: f64,
    pub anterior_ratio: f64,
    pub wall_mm: f64,
    pub bone_margin_mm: f64,
    /// A measured motion's files (a1, a2, a3, signal as given).
    pub files: Vec<String>,
    /// The fixed point's error at the signal's deepest breath (thesis §5.4.1), when the motion
    /// could be built.
    pub inversion: Option<InversionSummary>,
    /// Why the attached motion cannot be built on this atlas.
    pub problem: Option<String>,
}

#[derive(Debug, Clone, Serialize)]
pub struct InversionSummary {
    pub depth: f64,
    pub iterations: u32,
    pub points: usize,
    pub sliding: usize,
    pub worst_mm: f64,
    pub worst_all_mm: f64,
}

/// Points of the mobility map the load-time inversion check visits at most.
pub const INVERSION_POINTS: usize = 20_000;

impl BreathingSummary {
    /// Builds the attached motion and checks its inverse at the deepest breath of its signal
    /// (the measured one, else the default Lujan signal), with the views' 8 fixed-point steps.
    pub fn of(atlas: &Atlas) -> BreathingSummary {
        use stylet_physics::motion::{AtlasMotion, BreathingSignal, SignalParams, SyntheticField};
        let toml = atlas.manifest.breathing_or_default();
        let mut out = BreathingSummary {
            motion: toml.motion,
            amplitude_mm: toml.amplitude_mm,
            anterior_ratio: toml.anterior_ratio,
            wall_mm: toml.wall_mm,
            bone_margin_mm: toml.bone_margin_mm,
            files: toml.measured_files().into_iter().map(String::from).collect(),
            inversion: None,
            problem: None,
        };
        let iterations = stylet_physics::deform::resample::INVERSE_ITERATIONS;
        let lujan_depth = BreathingSignal::new(SignalParams::default()).map_or(1.0, |s| s.max_g());
        match atlas.model.breathing() {
            None => {}
            Some(AtlasMotion::Synthetic(motion)) => {
                match SyntheticField::new(std::sync::Arc::clone(&atlas.model), *motion) {
                    Ok(field) => {
                        let c = field.inversion_check(lujan_depth, iterations, INVERSION_POINTS);
                        out.inversion = Some(InversionSummary {
                            depth: c.depth,
                            iterations: c.iterations,
                            points: c.points,
                            sliding: c.sliding,
                            worst_mm: c.worst_mm,
                            worst_all_mm: c.worst_all_mm,
                        });
                    }
                    Err(e) => out.problem = Some(e.to_string()),
                }
            }
            Some(AtlasMotion::Measured(m)) => {
                let depth = m.signal.as_ref().map_or(lujan_depth, |s| s.max_g());
                let grid = m.a1.grid();
                let stride = grid.len().div_ceil(INVERSION_POINTS).max(1);
                let points: Vec<_> = (0..grid.len())
                    .step_by(stride)
                    .map(|i| grid.linear_to_world(i))
                    .collect();
                let worst = stylet_physics::motion::field_inversion_error_mm(&*m.a1, &points, depth, iterations);
                out.inversion = Some(InversionSummary {
                    depth,
                    iterations,
                    points: points.len(),
                    sliding: 0,
                    worst_mm: worst,
                    worst_all_mm: worst,
                });
            }
        }
        out
    }

    pub fn to_text(&self) -> String {
        if self.motion == MotionKind::None {
            return "breathing    none: this patient does not breathe\n".into();
        }
        let mut out = if self.motion == MotionKind::Measured {
            format!("breathing    measured fields: {}\n", self.files.join(", "))
        } else {
            format!(
                "breathing    synthetic motion, amplitude {} mm (anterior share {}), body wall {} mm, bone margin {} mm\n",
                self.amplitude_mm, self.anterior_ratio, self.wall_mm, self.bone_margin_mm
            )
        };
        if let Some(i) = &self.inversion
            && i.sliding == 0
        {
            out += &format!(
                "             inversion error at depth g = {:.2}, {} fixed-point steps: ≤ {:.2e} mm ({} points)\n",
                i.depth, i.iterations, i.worst_mm, i.points
            );
        } else if let Some(i) = &self.inversion {
            out += &format!(
                "             inversion error at depth g = {:.2}, {} fixed-point steps: ≤ {:.2e} mm in moving tissue ({} points); \
                 {:.1} mm with the {} points in a ramp or across the sliding interface\n",
                i.depth, i.iterations, i.worst_mm, i.points, i.worst_all_mm, i.sliding
            );
        }
        if let Some(p) = &self.problem {
            out += &format!("             cannot be built: {p}\n");
        }
        out
    }
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
            distance_maps: atlas.cache_status().describe(),
            labels,
            paths: atlas.manifest.paths.clone(),
            provenance: atlas.manifest.provenance.clone(),
            breathing: BreathingSummary::of(atlas),
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
        out += &format!("derived      distance maps {}\n", self.distance_maps);
        out += &format!("source       {}\n", self.provenance.source);
        out += &self.breathing.to_text();
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

//! The property tree: a hierarchy of tissue classes whose nodes define material parameters as a
//! scalar or as a piecewise-linear function of HU, inherited from the nearest ancestor when a node
//! leaves one undefined (thesis §6.1.3–6.1.4, docs/atlas.md).
//!
//! Evaluation for a location x (§6.1.4): (1) l = l(x, d); (2) find the node of label l; (3) if the
//! node defines the parameter, return the scalar or evaluate the function at I(x); (4) otherwise go
//! to the parent and repeat (3). [`Materials`] resolves step (4) once per label when the atlas
//! loads, so the 1 kHz loop only does (1) and (3).

use crate::complications::ComplicationKind;
use std::collections::BTreeMap;

use crate::{LabelTable, PhysicsError};

/// The material parameters the haptic algorithms read (thesis §3.5, §6.1.3; docs/atlas.md).
#[derive(Debug, Clone, Copy, PartialEq, Eq, PartialOrd, Ord, Hash)]
pub enum Param {
    /// f_k: tissue stiffness of the virtual springs between needle and path nodes [N/mm].
    StiffnessNPerMm,
    /// f_k1: linear spring of the cutting force before puncture [N/mm].
    CutSpringNPerMm,
    /// f_k2: quadratic spring of the cutting force before puncture [N/mm²].
    CutSpringNPerMm2,
    /// f_cutthresh: force the tip must exceed to cut forward (N).
    CutThresholdN,
    /// Maximum shaft friction per millimetre of path inside this tissue [N/mm]; the thesis'
    /// f_R per path segment is this value times the path spacing Δp.
    FrictionMaxNPerMm,
}

impl Param {
    pub const ALL: [Param; 5] = [
        Param::StiffnessNPerMm,
        Param::CutSpringNPerMm,
        Param::CutSpringNPerMm2,
        Param::CutThresholdN,
        Param::FrictionMaxNPerMm,
    ];
    pub const COUNT: usize = Param::ALL.len();

    /// The key used in `atlas.toml`.
    pub fn key(self) -> &'static str {
        match self {
            Param::StiffnessNPerMm => "stiffness_n_per_mm",
            Param::CutSpringNPerMm => "cut_spring_n_per_mm",
            Param::CutSpringNPerMm2 => "cut_spring_n_per_mm2",
            Param::CutThresholdN => "cut_threshold_n",
            Param::FrictionMaxNPerMm => "friction_max_n_per_mm",
        }
    }

    pub fn from_key(key: &str) -> Option<Param> {
        Param::ALL.into_iter().find(|p| p.key() == key)
    }

    #[inline]
    fn slot(self) -> usize {
        self as usize
    }
}

/// Why a parameter definition is refused; the property tree adds the tissue and parameter.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum ParamError {
    /// A value that is negative or not finite (every parameter is a physical magnitude).
    #[error("value {0} must be a finite number ≥ 0")]
    Value(f64),
    #[error("piecewise-linear function needs as many `hu` as `value` points (≥ 1), got {hu} and {values}")]
    PointCount { hu: usize, values: usize },
    #[error("breakpoint HU {0} is not finite")]
    BreakpointNotFinite(f64),
    /// The breakpoints (all of them) are not in strictly increasing HU.
    #[error("breakpoints must have strictly increasing HU, got {0:?}")]
    NotIncreasing(Vec<f64>),
}

/// A parameter definition: a constant, or a piecewise-linear function of HU (§6.1.3).
#[derive(Debug, Clone, PartialEq)]
pub enum ParamValue {
    Scalar(f64),
    /// Breakpoints (HU, value) with strictly increasing HU; constant beyond the first and last.
    PiecewiseLinear {
        hu: Vec<f64>,
        value: Vec<f64>,
    },
}

impl ParamValue {
    /// Checks finiteness, non-negativity (all parameters are physical magnitudes) and ordering.
    pub fn validate(&self) -> Result<(), ParamError> {
        match self {
            ParamValue::Scalar(v) => {
                if !v.is_finite() || *v < 0.0 {
                    return Err(ParamError::Value(*v));
                }
            }
            ParamValue::PiecewiseLinear { hu, value } => {
                if hu.is_empty() || hu.len() != value.len() {
                    return Err(ParamError::PointCount {
                        hu: hu.len(),
                        values: value.len(),
                    });
                }
                if let Some(v) = hu.iter().find(|v| !v.is_finite()) {
                    return Err(ParamError::BreakpointNotFinite(*v));
                }
                if let Some(v) = value.iter().find(|v| !v.is_finite() || **v < 0.0) {
                    return Err(ParamError::Value(*v));
                }
                if hu.windows(2).any(|w| w[0] >= w[1]) {
                    return Err(ParamError::NotIncreasing(hu.clone()));
                }
            }
        }
        Ok(())
    }

    /// The parameter at CT value `hu`.
    #[inline]
    pub fn eval(&self, hu: f64) -> f64 {
        match self {
            ParamValue::Scalar(v) => *v,
            ParamValue::PiecewiseLinear { hu: xs, value: ys } => {
                let n = xs.len();
                if hu <= xs[0] {
                    return ys[0];
                }
                if hu >= xs[n - 1] {
                    return ys[n - 1];
                }
                // Breakpoint lists are short (a handful), a linear scan is fastest.
                let mut s = 1;
                while xs[s] < hu {
                    s += 1;
                }
                let t = (hu - xs[s - 1]) / (xs[s] - xs[s - 1]);
                ys[s - 1] + t * (ys[s] - ys[s - 1])
            }
        }
    }
}

/// One tissue class as written in the atlas (before validation).
#[derive(Debug, Clone, PartialEq, Default)]
pub struct TissueSpec {
    pub name: String,
    pub parent: Option<String>,
    pub params: BTreeMap<Param, ParamValue>,
    /// Overlay colour RGBA (0–255), inherited like the parameters.
    pub color_rgba: Option<[u8; 4]>,
    /// What a needle through this tissue does to the patient, inherited like the parameters.
    pub complication: Option<ComplicationKind>,
}

#[derive(Debug, Clone, PartialEq)]
struct TissueNode {
    name: String,
    parent: Option<usize>,
    params: [Option<ParamValue>; Param::COUNT],
    color_rgba: Option<[u8; 4]>,
    complication: Option<ComplicationKind>,
}

/// A validated property tree: known parents, no cycles, valid parameter definitions.
#[derive(Debug, Clone, PartialEq)]
pub struct PropertyTree {
    nodes: Vec<TissueNode>,
    by_name: BTreeMap<String, usize>,
}

impl PropertyTree {
    pub fn new(specs: Vec<TissueSpec>) -> Result<Self, PhysicsError> {
        let mut by_name = BTreeMap::new();
        for (i, s) in specs.iter().enumerate() {
            if s.name.trim().is_empty() {
                return Err(PhysicsError::InvalidPropertyTree("a tissue has an empty name".into()));
            }
            if by_name.insert(s.name.clone(), i).is_some() {
                return Err(PhysicsError::InvalidPropertyTree(format!(
                    "tissue '{}' is defined twice",
                    s.name
                )));
            }
        }
        let mut nodes = Vec::with_capacity(specs.len());
        for s in &specs {
            let parent = match &s.parent {
                None => None,
                Some(p) => Some(*by_name.get(p).ok_or_else(|| {
                    PhysicsError::InvalidPropertyTree(format!("tissue '{}' has unknown parent '{}'", s.name, p))
                })?),
            };
            let mut params: [Option<ParamValue>; Param::COUNT] = Default::default();
            for (p, v) in &s.params {
                v.validate().map_err(|e| {
                    PhysicsError::InvalidPropertyTree(format!("tissue '{}', parameter '{}': {e}", s.name, p.key()))
                })?;
                params[p.slot()] = Some(v.clone());
            }
            nodes.push(TissueNode {
                name: s.name.clone(),
                parent,
                params,
                color_rgba: s.color_rgba,
                complication: s.complication,
            });
        }
        // Cycle check: walking up from any node must end within `nodes.len()` steps.
        for start in 0..nodes.len() {
            let mut at = start;
            let mut chain = vec![nodes[start].name.clone()];
            for _ in 0..=nodes.len() {
                match nodes[at].parent {
                    None => break,
                    Some(p) => {
                        at = p;
                        chain.push(nodes[p].name.clone());
                        if p == start {
                            return Err(PhysicsError::InvalidPropertyTree(format!(
                                "tissue tree has a cycle: {}",
                                chain.join(" → ")
                            )));
                        }
                    }
                }
            }
        }
        Ok(PropertyTree { nodes, by_name })
    }

    pub fn contains(&self, name: &str) -> bool {
        self.by_name.contains_key(name)
    }

    pub fn names(&self) -> impl Iterator<Item = &str> {
        self.nodes.iter().map(|n| n.name.as_str())
    }

    /// Ancestors of a tissue, itself first, root last.
    pub fn lineage(&self, name: &str) -> Option<Vec<&str>> {
        let mut at = *self.by_name.get(name)?;
        let mut out = vec![self.nodes[at].name.as_str()];
        while let Some(p) = self.nodes[at].parent {
            at = p;
            out.push(self.nodes[at].name.as_str());
        }
        Some(out)
    }

    pub fn parent(&self, name: &str) -> Option<&str> {
        let n = &self.nodes[*self.by_name.get(name)?];
        n.parent.map(|p| self.nodes[p].name.as_str())
    }

    /// Step (3)–(4) of §6.1.4: the definition of `param` for tissue `name`, searched from the node
    /// up to the root, with the name of the node that defines it.
    pub fn resolve(&self, name: &str, param: Param) -> Option<(&ParamValue, &str)> {
        let mut at = Some(*self.by_name.get(name)?);
        while let Some(i) = at {
            let n = &self.nodes[i];
            if let Some(v) = &n.params[param.slot()] {
                return Some((v, n.name.as_str()));
            }
            at = n.parent;
        }
        None
    }

    /// Whether `name` is the tissue `ancestor` or one of its descendants (a target duct is a bile
    /// duct).
    pub fn is_a(&self, name: &str, ancestor: &str) -> bool {
        let mut at = self.by_name.get(name).copied();
        while let Some(i) = at {
            if self.nodes[i].name == ancestor {
                return true;
            }
            at = self.nodes[i].parent;
        }
        false
    }

    /// The complication a puncture of a tissue causes, inherited like the parameters.
    pub fn resolve_complication(&self, name: &str) -> Option<ComplicationKind> {
        let mut at = Some(*self.by_name.get(name)?);
        while let Some(i) = at {
            if let Some(c) = self.nodes[i].complication {
                return Some(c);
            }
            at = self.nodes[i].parent;
        }
        None
    }

    /// The overlay colour of a tissue, inherited like the parameters.
    pub fn resolve_color(&self, name: &str) -> Option<[u8; 4]> {
        let mut at = Some(*self.by_name.get(name)?);
        while let Some(i) = at {
            if let Some(c) = self.nodes[i].color_rgba {
                return Some(c);
            }
            at = self.nodes[i].parent;
        }
        None
    }
}

/// Every label's parameters resolved through the tree once, for constant-time lookup.
#[derive(Debug, Clone, PartialEq)]
pub struct Materials {
    /// Indexed by the label's position in the label table.
    per_label: Vec<[ParamValue; Param::COUNT]>,
    colors: Vec<[u8; 4]>,
}

impl Materials {
    /// Resolves all labels; fails naming the first label and parameter without a definition.
    pub fn resolve(labels: &LabelTable, tree: &PropertyTree) -> Result<Self, PhysicsError> {
        let mut per_label = Vec::with_capacity(labels.labels().len());
        let mut colors = Vec::with_capacity(labels.labels().len());
        for l in labels.labels() {
            if !tree.contains(&l.tissue) {
                return Err(PhysicsError::InvalidPropertyTree(format!(
                    "label '{}' (id {}) refers to unknown tissue '{}'",
                    l.name, l.id, l.tissue
                )));
            }
            let mut row: Vec<ParamValue> = Vec::with_capacity(Param::COUNT);
            for p in Param::ALL {
                match tree.resolve(&l.tissue, p) {
                    Some((v, _)) => row.push(v.clone()),
                    None => {
                        let lineage = tree.lineage(&l.tissue).unwrap_or_default().join(" → ");
                        return Err(PhysicsError::InvalidPropertyTree(format!(
                            "label '{}' has no value for '{}' in tissue '{}' or its ancestors ({lineage})",
                            l.name,
                            p.key(),
                            l.tissue
                        )));
                    }
                }
            }
            per_label.push(row.try_into().expect("one value per parameter"));
            colors.push(tree.resolve_color(&l.tissue).unwrap_or([128, 128, 128, 128]));
        }
        Ok(Materials { per_label, colors })
    }

    /// Parameter `param` of the label at table position `pos` for CT value `hu`.
    #[inline]
    pub fn eval(&self, pos: usize, param: Param, hu: f64) -> f64 {
        self.per_label[pos][param.slot()].eval(hu)
    }

    /// The definition (scalar or function) of `param` for the label at table position `pos`.
    pub fn value(&self, pos: usize, param: Param) -> &ParamValue {
        &self.per_label[pos][param.slot()]
    }

    pub fn color(&self, pos: usize) -> [u8; 4] {
        self.colors[pos]
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn spec(name: &str, parent: Option<&str>, params: &[(Param, ParamValue)]) -> TissueSpec {
        TissueSpec {
            name: name.into(),
            parent: parent.map(Into::into),
            params: params.iter().cloned().collect(),
            color_rgba: None,
            complication: None,
        }
    }

    #[test]
    fn piecewise_linear_interpolates_and_clamps() {
        let f = ParamValue::PiecewiseLinear {
            hu: vec![-100.0, 0.0, 100.0],
            value: vec![1.0, 2.0, 6.0],
        };
        assert_eq!(f.eval(-500.0), 1.0);
        assert_eq!(f.eval(-50.0), 1.5);
        assert_eq!(f.eval(50.0), 4.0);
        assert_eq!(f.eval(1000.0), 6.0);
        let bad = ParamValue::PiecewiseLinear {
            hu: vec![0.0, 0.0],
            value: vec![1.0, 2.0],
        };
        assert!(bad.validate().unwrap_err().to_string().contains("strictly increasing"));
    }

    #[test]
    fn parameters_inherit_from_the_nearest_ancestor() {
        let tree = PropertyTree::new(vec![
            spec(
                "body",
                None,
                &[
                    (Param::CutThresholdN, ParamValue::Scalar(1.0)),
                    (Param::StiffnessNPerMm, ParamValue::Scalar(0.1)),
                ],
            ),
            spec("soft", Some("body"), &[(Param::CutThresholdN, ParamValue::Scalar(0.5))]),
            spec("liver", Some("soft"), &[]),
        ])
        .unwrap();
        let (v, at) = tree.resolve("liver", Param::CutThresholdN).unwrap();
        assert_eq!((v.eval(0.0), at), (0.5, "soft"));
        let (v, at) = tree.resolve("liver", Param::StiffnessNPerMm).unwrap();
        assert_eq!((v.eval(0.0), at), (0.1, "body"));
        assert!(tree.resolve("liver", Param::FrictionMaxNPerMm).is_none());
        assert_eq!(tree.lineage("liver").unwrap(), vec!["liver", "soft", "body"]);
    }

    #[test]
    fn unknown_parent_and_cycles_are_rejected() {
        let e = PropertyTree::new(vec![spec("a", Some("nope"), &[])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("unknown parent 'nope'"), "{e}");
        let e = PropertyTree::new(vec![
            spec("a", Some("b"), &[]),
            spec("b", Some("c"), &[]),
            spec("c", Some("a"), &[]),
        ])
        .unwrap_err()
        .to_string();
        assert!(e.contains("cycle"), "{e}");
        let e = PropertyTree::new(vec![spec("a", Some("a"), &[])])
            .unwrap_err()
            .to_string();
        assert!(e.contains("cycle"), "{e}");
        let e = PropertyTree::new(vec![spec(
            "a",
            None,
            &[(Param::CutThresholdN, ParamValue::Scalar(-1.0))],
        )])
        .unwrap_err()
        .to_string();
        assert!(e.contains("cut_threshold_n"), "{e}");
    }
}

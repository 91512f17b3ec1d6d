//! One solved displacement field on its placement of Ω_J, and the solve that makes it from the
//! previous one (thesis Alg. 4.1): place the lattice around the tool, warm-start from the
//! previous field shifted by whole nodes, impose eqs. 4.2.5–4.2.7, run the schedule.

use std::collections::BTreeMap;
use std::sync::Arc;

use glam::DVec3;
use rayon::prelude::*;

use super::lattice::Lattice;
use super::material::f_mat;
use super::solver::{self, Components, Level};
use super::{DeformSettings, ToolPoint};
use crate::{PunctureAtlas, Role};

/// What depends only on where Ω_J lies: hard tissue, f_mat and risk structures per node, and the
/// multigrid levels with those conditions (each solve adds its tool nodes to a copy of their
/// `fixed` flags and shares f_mat).
#[derive(Debug)]
pub struct Placement {
    pub lattice: Lattice,
    /// Finest first; `levels[0].fixed`: border or hard tissue (HU ≥ t_fat→bone), u = 0
    /// (eqs. 4.2.5–4.2.6).
    levels: Vec<Level>,
    /// The node lies in a segmented risk structure (partial labels, role risk).
    pub risk: Vec<bool>,
}

impl Placement {
    fn new(atlas: &PunctureAtlas, s: &DeformSettings, lattice: Lattice) -> Placement {
        let n = lattice.n;
        let bone_hu = atlas.thresholds().fat_bone_hu;
        let table = atlas.label_table();
        let mut fixed = vec![false; lattice.len()];
        let mut fm = vec![0.0; lattice.len()];
        let mut risk = vec![false; lattice.len()];
        fixed
            .par_chunks_mut(n * n)
            .zip(fm.par_chunks_mut(n * n))
            .zip(risk.par_chunks_mut(n * n))
            .enumerate()
            .for_each(|(k, ((fx, fm), rk))| {
                for j in 0..n {
                    for i in 0..n {
                        let x = lattice.position(i, j, k);
                        let hu = atlas.hu_at(x);
                        let o = i + n * j;
                        fx[o] = lattice.is_border(i, j, k) || hu >= bone_hu;
                        fm[o] = f_mat(hu, s.material_k_per_hu, s.material_s_hu);
                        let label = atlas.partial_label_at(x);
                        rk[o] = label != 0 && table.get(label).is_some_and(|l| l.role == Role::Risk);
                    }
                }
            });
        let finest = Level {
            lattice,
            fixed,
            f_mat: fm.into(),
        };
        Placement {
            lattice,
            levels: solver::hierarchy(finest, s.schedule.levels),
            risk,
        }
    }

    /// Border and hard-tissue nodes (u = 0).
    pub fn fixed(&self) -> &[bool] {
        &self.levels[0].fixed
    }

    /// f_mat at each node (eq. 4.2.17).
    pub fn f_mat(&self) -> &[f64] {
        &self.levels[0].f_mat
    }
}

/// A solved field u (reference → world: x = X + u(X), eq. 4.2.1) on its lattice.
#[derive(Debug, Clone)]
pub struct DeformField {
    placement: Arc<Placement>,
    /// u by component (x, y, z), node index as [`Lattice::index`].
    u: Components,
    /// Nodes that carried a tool condition in this solve.
    tool_nodes: usize,
    digest: u64,
    max_mm: f64,
    risk_max_mm: f64,
}

impl DeformField {
    pub fn lattice(&self) -> &Lattice {
        &self.placement.lattice
    }
    pub fn placement(&self) -> &Placement {
        &self.placement
    }
    /// The displacement at node `idx` (mm), index as [`Lattice::index`].
    #[inline]
    pub fn node(&self, idx: usize) -> DVec3 {
        DVec3::new(self.u[0][idx], self.u[1][idx], self.u[2][idx])
    }
    /// Every nodal displacement (mm), index as [`Lattice::index`] (a copy).
    pub fn displacements(&self) -> Vec<DVec3> {
        solver::join(&self.u)
    }
    /// The nodal displacements by component (x, y, z).
    pub fn components(&self) -> &Components {
        &self.u
    }
    /// u(X) by trilinear interpolation, zero outside Ω_J.
    pub fn displacement(&self, x_ref: DVec3) -> DVec3 {
        self.placement.lattice.sample_with(|i| self.node(i), x_ref)
    }
    pub fn tool_nodes(&self) -> usize {
        self.tool_nodes
    }
    /// Largest |u| over the nodes (mm).
    pub fn max_displacement_mm(&self) -> f64 {
        self.max_mm
    }
    /// Largest |u| over nodes inside segmented risk structures (mm): a vessel pushed aside.
    pub fn risk_displacement_mm(&self) -> f64 {
        self.risk_max_mm
    }
    /// Hash of the lattice origin and every displacement bit (computed once per solve).
    pub fn digest(&self) -> u64 {
        self.digest
    }

    /// The reference point X with X + u(X) = `x_world`, by the fixed point X⁺ = x − u(X)
    /// (thesis §4.3.1, [CLC⁺08]); converges where u is a contraction (|∇u| < 1).
    pub fn to_reference(&self, x_world: DVec3, iterations: u32) -> DVec3 {
        let mut x = x_world;
        for _ in 0..iterations {
            x = x_world - self.displacement(x);
        }
        x
    }
}

/// Where Ω_J goes for a tool at `centre`: kept while the centre stays within an eighth of the
/// cube of the current centre, else re-centred on the world lattice of spacing h (so a shift is
/// a whole number of nodes and the warm start copies exactly).
fn place(s: &DeformSettings, prev: Option<&Lattice>, centre: DVec3) -> Lattice {
    let n = s.cells as usize + 1;
    let h = s.spacing_mm;
    if let Some(p) = prev
        && p.n == n
        && p.h_mm == h
        && (centre - p.centre()).abs().max_element() <= h * n as f64 / 8.0
    {
        return *p;
    }
    let half = 0.5 * h * (n - 1) as f64;
    let snap = |v: f64| libm::round((v - half) / h) * h;
    Lattice {
        n,
        h_mm: h,
        origin_mm: DVec3::new(snap(centre.x), snap(centre.y), snap(centre.z)),
    }
}

/// The previous field on the new lattice (whole-node shift), zero where it did not reach.
fn warm_start(prev: Option<&DeformField>, lattice: &Lattice) -> Components {
    let len = lattice.len();
    let zero = || [vec![0.0; len], vec![0.0; len], vec![0.0; len]];
    let Some(prev) = prev else { return zero() };
    let p = prev.lattice();
    if p.n != lattice.n || p.h_mm != lattice.h_mm {
        return zero();
    }
    if p.origin_mm == lattice.origin_mm {
        // A plain copy, a plane per task (megabytes: one core's memcpy is the slower way).
        let mut u = [vec![0.0; len], vec![0.0; len], vec![0.0; len]];
        let n2 = lattice.n * lattice.n;
        for (dst, src) in u.iter_mut().zip(&prev.u) {
            dst.par_chunks_mut(n2)
                .zip(src.par_chunks(n2))
                .for_each(|(d, s)| d.copy_from_slice(s));
        }
        return u;
    }
    let off = (lattice.origin_mm - p.origin_mm) / p.h_mm;
    let off = [
        libm::round(off.x) as i64,
        libm::round(off.y) as i64,
        libm::round(off.z) as i64,
    ];
    let n = lattice.n as i64;
    let mut u = zero();
    for (a, comp) in u.iter_mut().enumerate() {
        comp.par_chunks_mut((n * n) as usize)
            .enumerate()
            .for_each(|(k, plane)| {
                let c = k as i64 + off[2];
                if !(0..n).contains(&c) {
                    return;
                }
                for j in 0..n {
                    let b = j + off[1];
                    if !(0..n).contains(&b) {
                        continue;
                    }
                    // Row j of the new plane takes row b of the old plane c, shifted by off[0].
                    let (lo, hi) = ((-off[0]).max(0), (n - off[0]).min(n));
                    if lo >= hi {
                        continue;
                    }
                    let src = p.index((lo + off[0]) as usize, b as usize, c as usize);
                    let dst = (j * n + lo) as usize;
                    plane[dst..dst + (hi - lo) as usize].copy_from_slice(&prev.u[a][src..src + (hi - lo) as usize]);
                }
            });
    }
    u
}

/// Tool conditions of eq. 4.2.7 on the nearest interior node of each point, or on every interior
/// node within its radius; several points on one node are averaged in the order given.
fn tool_conditions(lattice: &Lattice, points: &[ToolPoint]) -> BTreeMap<usize, DVec3> {
    let mut acc: BTreeMap<usize, (DVec3, f64)> = BTreeMap::new();
    let mut add = |i: usize, j: usize, k: usize, v: DVec3| {
        if !lattice.is_border(i, j, k) {
            let e = acc.entry(lattice.index(i, j, k)).or_insert((DVec3::ZERO, 0.0));
            e.0 += v;
            e.1 += 1.0;
        }
    };
    for p in points {
        if !(p.reference_mm.is_finite() && p.displacement_mm.is_finite() && p.radius_mm.is_finite()) {
            continue;
        }
        // At most a few nodes' radius: a patch, not a volume.
        let r = p.radius_mm.clamp(0.0, 4.0 * lattice.h_mm);
        if r == 0.0 {
            if let Some([i, j, k]) = lattice.nearest(p.reference_mm) {
                add(i, j, k, p.displacement_mm);
            }
            continue;
        }
        let c = (p.reference_mm - lattice.origin_mm) / lattice.h_mm;
        let reach = r / lattice.h_mm;
        let last = (lattice.n - 1) as f64;
        let lo = (c - DVec3::splat(reach)).ceil().max(DVec3::ZERO);
        let hi = (c + DVec3::splat(reach)).floor().min(DVec3::splat(last));
        if lo.x > hi.x || lo.y > hi.y || lo.z > hi.z {
            continue;
        }
        for k in lo.z as usize..=hi.z as usize {
            for j in lo.y as usize..=hi.y as usize {
                for i in lo.x as usize..=hi.x as usize {
                    if (lattice.position(i, j, k) - p.reference_mm).length() <= r {
                        add(i, j, k, p.displacement_mm);
                    }
                }
            }
        }
    }
    acc.into_iter().map(|(i, (s, c))| (i, s / c)).collect()
}

/// The Dirichlet nodes and values of a solve on `lattice` (border, hard tissue: 0; tool
/// points: ũ) as the solve imposes them, for comparisons with other solvers.
pub fn dirichlet(
    atlas: &PunctureAtlas,
    s: &DeformSettings,
    lattice: &Lattice,
    points: &[ToolPoint],
) -> (Vec<bool>, Vec<DVec3>) {
    let placement = Placement::new(atlas, s, *lattice);
    let mut fixed = placement.fixed().to_vec();
    let mut u = vec![DVec3::ZERO; lattice.len()];
    for (i, v) in tool_conditions(lattice, points) {
        fixed[i] = true;
        u[i] = v;
    }
    (fixed, u)
}

/// One solve of Alg. 4.1: the field for tool conditions `points` around `centre`, warm-started
/// from `prev`. A pure function of its arguments.
pub fn solve(
    atlas: &PunctureAtlas,
    s: &DeformSettings,
    prev: Option<&DeformField>,
    centre: DVec3,
    points: &[ToolPoint],
) -> DeformField {
    let lattice = place(s, prev.map(DeformField::lattice), centre);
    let placement = match prev {
        Some(p) if *p.lattice() == lattice => Arc::clone(&p.placement),
        _ => Arc::new(Placement::new(atlas, s, lattice)),
    };
    let conditions = tool_conditions(&lattice, points);
    let len = lattice.len();
    let mut u = if conditions.is_empty() {
        // Only u = 0 conditions: the converged field is zero; the tissue springs back.
        [vec![0.0; len], vec![0.0; len], vec![0.0; len]]
    } else {
        let mut u = warm_start(prev, &lattice);
        let fixed = placement.fixed();
        for comp in u.iter_mut() {
            comp.iter_mut()
                .zip(fixed)
                .for_each(|(v, &f)| *v = if f { 0.0 } else { *v });
        }
        let mut tool_nodes = Vec::with_capacity(conditions.len());
        for (&i, &v) in &conditions {
            tool_nodes.push(i);
            for a in 0..3 {
                u[a][i] = v[a];
            }
        }
        let levels = solver::with_fixed(&placement.levels, &tool_nodes);
        solver::solve(&levels, s.regulariser, &s.schedule, &mut u, None);
        u
    };
    // Per plane in parallel (non-finite values zeroed, a hash, the largest |u| overall and in
    // risk structures), then combined in plane order: the same bits on any number of threads.
    // Each task hashes four planes with their chains interleaved (a hash is a chain of
    // dependent multiplies; four at once keep the multiplier busy).
    let n = lattice.n;
    let [ux, uy, uz] = &mut u;
    const GROUP: usize = 4;
    let groups: Vec<[(u64, f64, f64); GROUP]> = ux
        .par_chunks_mut(GROUP * n * n)
        .zip(uy.par_chunks_mut(GROUP * n * n))
        .zip(uz.par_chunks_mut(GROUP * n * n))
        .zip(placement.risk.par_chunks(GROUP * n * n))
        .map(|(((x, y), z), risk)| {
            let planes = x.len() / (n * n);
            let mut h = [(); GROUP].map(|()| super::Fnv64::new());
            let (mut max_mm, mut risk_max_mm) = ([0.0f64; GROUP], [0.0f64; GROUP]);
            for o in 0..n * n {
                for p in 0..planes {
                    let i = p * n * n + o;
                    let mut v = DVec3::new(x[i], y[i], z[i]);
                    if !v.is_finite() {
                        v = DVec3::ZERO;
                        (x[i], y[i], z[i]) = (0.0, 0.0, 0.0);
                    }
                    h[p].f64(v.x);
                    h[p].f64(v.y);
                    h[p].f64(v.z);
                    let l = v.length();
                    max_mm[p] = max_mm[p].max(l);
                    if risk[i] {
                        risk_max_mm[p] = risk_max_mm[p].max(l);
                    }
                }
            }
            std::array::from_fn(|p| (h[p].finish(), max_mm[p], risk_max_mm[p]))
        })
        .collect();
    let planes = groups.into_iter().flatten().take(n);
    let mut h = super::Fnv64::new();
    h.f64(lattice.origin_mm.x);
    h.f64(lattice.origin_mm.y);
    h.f64(lattice.origin_mm.z);
    let (mut max_mm, mut risk_max_mm) = (0.0f64, 0.0f64);
    for (ph, m, r) in planes {
        h.u64(ph);
        max_mm = max_mm.max(m);
        risk_max_mm = risk_max_mm.max(r);
    }
    DeformField {
        placement,
        u,
        tool_nodes: conditions.len(),
        digest: h.finish(),
        max_mm,
        risk_max_mm,
    }
}

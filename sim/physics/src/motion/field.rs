//! Displacement fields over reference space: what a motion model combines over time (the u_j of
//! the key frames, thesis eq. 5.3.1; the a₁, a₂, a₃ of the surrogate model, eq. 5.3.6).

use glam::DVec3;

use crate::{Grid, Volume};

/// A displacement field X ↦ v(X) (mm → mm) over reference space. Implementations must be pure.
pub trait SpatialField: Send + Sync {
    fn at(&self, x_ref: DVec3) -> DVec3;

    /// A bound on |v(X)| over all X (mm).
    fn max_length_mm(&self) -> f64;

    /// The field as a [`FactoredField`], when it has that form.
    fn factored(&self) -> Option<FactoredField<'_>> {
        None
    }

    /// The field as a [`GridField`], when it is one (measured motion).
    fn as_grid(&self) -> Option<&GridField> {
        None
    }
}

/// A field of the form v(X) = Σᵢ wᵢ · fᵢ(X): up to three [`GridField`]s, each scaled — the
/// surrogate model at one moment (thesis eq. 5.3.6: a₁ by g(t), a₂ by g′(t), a₃ by 1) when its
/// fields are measured. The form a GPU draws: the fields uploaded once, the weights written per
/// frame (docs/breathing.md "On the GPU").
#[derive(Clone, Copy)]
pub struct WeightedGrids<'a> {
    /// (field, weight) in the order a₁, a₂, a₃; absent terms are `None`.
    pub terms: [Option<(&'a GridField, f64)>; 3],
}

/// A field of the form v(X) = d · w(X.z) · m(X): a constant direction d, a piecewise-linear
/// profile w along z (knots (z mm, w) ascending, constant beyond the ends) and a scalar map m
/// read trilinearly on a grid, zero outside it. The form a GPU draws: m uploaded once, d scaled
/// per frame (docs/breathing.md "On the GPU").
#[derive(Clone, Copy)]
pub struct FactoredField<'a> {
    pub direction_mm: DVec3,
    pub profile: [(f64, f64); 4],
    pub map: &'a Volume<f32>,
}

/// Why displacement values do not make a [`GridField`]: the importer adds which file they came
/// from.
#[derive(Debug, thiserror::Error, Clone, PartialEq)]
pub enum GridFieldError {
    /// Not one vector per grid node.
    #[error("{values} displacement vectors for a grid of {nodes} nodes")]
    Count { values: usize, nodes: usize },
    /// The first node (x, y, z) whose displacement is NaN or infinite.
    #[error("the displacement at node ({}, {}, {}) is not finite", node[0], node[1], node[2])]
    NotFinite { node: [usize; 3] },
}

/// A field sampled on a grid (an imported registration result, a generated key frame),
/// interpolated trilinearly; zero outside the grid's sampling domain.
#[derive(Debug, Clone)]
pub struct GridField {
    grid: Grid,
    /// (x, y, z) per node in the grid's linear order (mm).
    values: Vec<[f32; 3]>,
}

impl GridField {
    /// A field of `values` on `grid` (one vector per node), refused when the counts differ or a
    /// value is not finite.
    pub fn new(grid: Grid, values: Vec<[f32; 3]>) -> Result<GridField, GridFieldError> {
        if values.len() != grid.len() {
            return Err(GridFieldError::Count {
                values: values.len(),
                nodes: grid.len(),
            });
        }
        if let Some(i) = values.iter().position(|v| !v.iter().all(|c| c.is_finite())) {
            return Err(GridFieldError::NotFinite { node: grid.unlinear(i) });
        }
        Ok(GridField { grid, values })
    }

    /// A field sampled from `f` at every node of `grid`.
    pub fn sample(grid: Grid, f: impl Fn(DVec3) -> DVec3) -> GridField {
        let values = (0..grid.len())
            .map(|i| {
                let v = f(grid.linear_to_world(i));
                [v.x as f32, v.y as f32, v.z as f32]
            })
            .collect();
        GridField { grid, values }
    }

    pub fn grid(&self) -> &Grid {
        &self.grid
    }

    /// (x, y, z) per node in the grid's linear order (mm).
    pub fn values(&self) -> &[[f32; 3]] {
        &self.values
    }
}

impl SpatialField for GridField {
    /// The largest displacement on the grid: trilinear interpolation never exceeds it.
    fn max_length_mm(&self) -> f64 {
        self.values
            .iter()
            .map(|v| DVec3::new(v[0] as f64, v[1] as f64, v[2] as f64).length())
            .fold(0.0, f64::max)
    }

    fn as_grid(&self) -> Option<&GridField> {
        Some(self)
    }

    fn at(&self, x_ref: DVec3) -> DVec3 {
        let c = self.grid.world_to_index(x_ref);
        crate::volume::trilinear(c, self.grid.dims(), |i, j, k| {
            let p = self.values[self.grid.linear(i, j, k)];
            DVec3::new(p[0] as f64, p[1] as f64, p[2] as f64)
        })
        .unwrap_or(DVec3::ZERO)
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn a_linear_field_is_reproduced_inside_and_zero_outside() {
        let affine = crate::Affine::from_spacing([2.0, 3.0, 4.0], DVec3::new(-4.0, -6.0, -8.0));
        let grid = Grid::new([5, 6, 7], affine).unwrap();
        let lin = |x: DVec3| DVec3::new(0.1 * x.y + 1.0, -0.2 * x.z, 0.05 * x.x);
        let f = GridField::sample(grid, lin);
        for p in [DVec3::new(0.3, 1.7, -2.2), DVec3::new(-3.0, 6.5, 12.0), DVec3::ZERO] {
            assert!((f.at(p) - lin(p)).length() < 1e-5, "{p}");
        }
        assert_eq!(f.at(DVec3::new(100.0, 0.0, 0.0)), DVec3::ZERO);
        assert!(GridField::new(grid, vec![[0.0; 3]; 3]).is_err());
        let mut bad = vec![[0.0f32; 3]; grid.len()];
        bad[7][1] = f32::NAN;
        assert!(
            GridField::new(grid, bad)
                .unwrap_err()
                .to_string()
                .contains("not finite")
        );
    }
}

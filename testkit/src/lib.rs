//! Test support shared by the workspace's test suites.

mod fixture_dir;
mod real_ct;

pub use fixture_dir::fixture_dir;
pub use real_ct::{real_ct_data, real_ct_data_dir};
